"""Training DOPE (``pegasus train``): one network per object, on BOP datasets or DOPE/NDDS folders, on CPU
or CUDA, in one process or under ``torchrun`` (DDP).

Output folder:
  ``last.pt``            the newest checkpoint (``checkpoint``: model, optimizer, epochs and steps done,
                         model and training config, the object); ``--resume`` continues it
  ``epoch_NNNN.pt``      the checkpoint after the first epoch, then every ``checkpoint_every`` epochs at least
                         ``checkpoint_minutes`` apart, and after the last (``keep_checkpoints`` newest kept)
  ``loss.csv``           one row per optimisation step: step, epoch, loss (mean over ranks), images (over
                         all ranks), images_per_s, lr; a resumed run first drops rows past its checkpoint
  ``loss.png``           the curve (per step and epoch means), redrawn with each checkpoint
  ``beliefs/epoch_NNNN.png`` the first training image (no augmentation) with its target and the
                         predicted beliefs of the last stage
  ``train_config.yaml``  the configuration

Distributed: each rank reads a disjoint shard of a permutation drawn per epoch from (seed, epoch); the
shards cover the dataset exactly once (torch's DistributedSampler pads with repeats instead), ranks with
one batch fewer are handled by DDP's ``join``. Only rank 0 writes files.
"""

from __future__ import annotations

import contextlib
import csv
import math
import os
import shutil
import time
from dataclasses import asdict, replace
from pathlib import Path

import cv2
import numpy as np
import torch
import trimesh
import yaml
from tqdm import tqdm

from dope_training.backbone import load_pretrained
from dope_training.backgrounds import load_photos, split_photos
from dope_training.checkpoint import CHECKPOINT_FORMAT, TargetObject, load_checkpoint
from dope_training.data import HIDDEN_VISIBILITY, Augment, DopeDataset, load_bop, load_ndds, resolve_objects
from dope_training.keypoints import surface_keypoints
from dope_training.model import (
    DopeNetwork,
    ModelConfig,
    check_memory,
    dope_loss,
    load_vgg19_weights,
    memory_estimate,
    memory_limit,
    model_config,
    torch_device,
)
from dope_training.train_config import TrainConfig
from pegasus_gen.errors import PegasusError
from pegasus_gen.formats.bop import model_boxes, object_names, read_model
from pegasus_gen.io import images
from pegasus_gen.io.files import link_atomic, read_json, write_atomic
from pegasus_gen.io.lock import LOCK_FILE, FolderLock
from pegasus_gen.io.plots import line_chart

# Keys a resumed run may change; any other difference means another experiment and is refused.
RESUMABLE_KEYS = {"epochs", "device", "loader_workers", "keep_checkpoints", "checkpoint_every", "checkpoint_minutes",
                  "out"}


SURFACE_SAMPLES = 500  # model surface points a checkpoint carries for depth refinement


def surface_samples(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """Points and unit normals [SURFACE_SAMPLES, 3] (the mesh's units, model frame) on ``mesh`` (a BOP model,
    ``read_model``: metres), area-uniform, the same for every run."""
    points, faces = trimesh.sample.sample_surface(mesh, SURFACE_SAMPLES, seed=0)
    return points, mesh.face_normals[faces]


def load_training_samples(cfg: TrainConfig):
    """(samples from every ``cfg.data`` entry, the TargetObject)."""
    samples, target = [], None
    for entry in cfg.data:
        root = Path(entry)
        if (root / "models" / "models_info.json").is_file():
            boxes = model_boxes(root)
            names = object_names(root)
            obj_id = resolve_objects([cfg.object], boxes, names, str(root))[0]
            info = read_json(root / "models" / "models_info.json")[str(obj_id)]
            name = next((n for n, i in names.items() if i == obj_id), str(obj_id))
            axis = cfg.symmetry_axis or next((s["axis"] for s in info.get("symmetries_continuous", [])), None)
            symmetric = bool(info.get("symmetries_discrete")) or axis is not None
            mesh = read_model(root, obj_id)
            points, normals = surface_samples(mesh)
            keypoints = surface_keypoints(mesh, *boxes[obj_id], cfg.surface_points) if cfg.keypoints == "surface" \
                else None
            found = TargetObject(obj_id, name, boxes[obj_id][0].tolist(), boxes[obj_id][1].tolist(), symmetric,
                                 points.tolist(), normals.tolist(), None if axis is None else list(axis),
                                 None if keypoints is None else keypoints.tolist())
            samples += load_bop(root, [obj_id], cfg.split, cfg.min_visibility, axis, keep_empty=cfg.negatives > 0,
                                keypoints=None if keypoints is None else {obj_id: keypoints})
        elif root.is_dir():
            if cfg.keypoints != "cuboid":
                raise PegasusError(f"{root}: a DOPE/NDDS folder labels the cuboid only (--keypoints cuboid)")
            if cfg.object_size is None:
                raise PegasusError(f"{root}: a DOPE/NDDS folder needs --object-size X Y Z (metres) for the cuboid")
            size = np.asarray(cfg.object_size, float)
            found = TargetObject(1, cfg.object, (-size / 2).tolist(), size.tolist())
            samples += load_ndds(root, [cfg.object], cfg.min_visibility)
        else:
            raise PegasusError(f"{root}: no such dataset folder")
        if target is not None and not np.allclose(target.bbox_size, found.bbox_size, atol=1e-4):
            raise PegasusError(f"{root}: object {cfg.object!r} has another model box than in {cfg.data[0]}")
        target = target or found
    if not any(s.keypoints for s in samples):
        raise PegasusError(f"no image shows {cfg.object!r} at visibility >= {cfg.min_visibility} in {cfg.data}")
    return samples, target


def crop_augment(cfg: TrainConfig) -> Augment:
    """The training crops' augmentation ``cfg`` asks for (colour jitter, hue turn, blur; all of it off without
    ``cfg.augment``)."""
    return Augment(brightness=cfg.colour_jitter, contrast=cfg.colour_jitter, saturation=cfg.colour_jitter,
                   hue_deg=cfg.hue_deg, blur_px=cfg.blur_px, linear_light=cfg.blur_linear_light, enabled=cfg.augment)


def learning_rate(cfg: TrainConfig, step: int, total_steps: int) -> float:
    """The learning rate of optimisation step ``step`` (0-based) of ``total_steps``: ``cfg.lr``, or with the
    cosine schedule lr * (0.01 + 0.99 * (1 + cos(pi * step / total_steps)) / 2)."""
    if cfg.schedule == "constant":
        return cfg.lr
    return cfg.lr * (0.01 + 0.99 * (1 + math.cos(math.pi * min(step / max(total_steps, 1), 1.0))) / 2)


class ShardSampler(torch.utils.data.Sampler):
    """This rank's share of a permutation of range(n) drawn from (seed, epoch), as (epoch, index) keys of
    :class:`DopeDataset`: ranks together visit every index exactly once per epoch. With ``weights`` [n] (>= 0, not
    all 0) each epoch is instead n draws with replacement, index i with probability weights[i] / sum(weights)."""

    def __init__(self, n: int, rank: int = 0, world: int = 1, seed: int = 0, weights: np.ndarray | None = None):
        self.n, self.rank, self.world, self.seed, self.epoch = n, rank, world, seed, 0
        self.p = None if weights is None else np.asarray(weights, float) / np.sum(weights)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __iter__(self):
        rng = np.random.default_rng([self.seed, self.epoch])
        order = rng.permutation(self.n) if self.p is None else rng.choice(self.n, self.n, p=self.p)
        return iter((self.epoch, i) for i in order[self.rank::self.world].tolist())

    def __len__(self) -> int:
        return len(range(self.rank, self.n, self.world))


def hidden_weights(samples: list, share: float) -> np.ndarray | None:
    """Draw weights [len(samples)] that give the samples with an instance under HIDDEN_VISIBILITY visible ``share``
    of the draws and the rest the remainder, each sample of a group alike; None (every sample once per epoch) for
    ``share`` 0 or where one of the groups is empty."""
    hidden = np.array([any(v < HIDDEN_VISIBILITY for v in s.visibility) for s in samples])
    if share <= 0 or hidden.all() or not hidden.any():
        return None
    return np.where(hidden, share / hidden.sum(), (1 - share) / (~hidden).sum())


def _distributed() -> tuple[int, int, int]:
    """(rank, world size, local rank) from torchrun's environment; (0, 1, 0) without it."""
    return int(os.environ.get("RANK", 0)), int(os.environ.get("WORLD_SIZE", 1)), int(os.environ.get("LOCAL_RANK", 0))


def read_losses(path: Path) -> list[dict]:
    """The rows of a run's loss.csv (step and epoch as int, the rest float); [] when there is none."""
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        return [{k: int(v) if k in ("step", "epoch") else float(v) for k, v in row.items()}
                for row in csv.DictReader(f)]


LOSS_FIELDS = ("step", "epoch", "loss", "images", "images_per_s", "lr")


def _write_losses(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, LOSS_FIELDS)
        writer.writeheader()
        writer.writerows(rows)


def loss_curve(rows: list[dict]) -> np.ndarray:
    """RGB image of the loss per step and its mean per epoch, at the end of each (x: epochs done)."""
    steps = np.array([r["step"] for r in rows])
    epochs = np.array([r["epoch"] for r in rows])
    loss = np.array([r["loss"] for r in rows])
    x = np.empty(len(rows))
    for e in np.unique(epochs):  # spread each epoch's steps over (e, e + 1]
        at = np.flatnonzero(epochs == e)
        x[at] = e + (steps[at] - steps[at].min() + 1) / len(at)
    ends = [(e + 1, loss[epochs == e].mean()) for e in np.unique(epochs)]
    series = {"loss per step": (x, loss), "epoch mean": tuple(np.array(ends).T) if ends else ([], [])}
    return line_chart(series, "DOPE training loss", "epoch", "loss", log_y=True)


def belief_snapshot(model: DopeNetwork, crop: np.ndarray, target: np.ndarray, device: torch.device) -> np.ndarray:
    """RGB image: the crop [S, S, 3] uint8, the target beliefs' max over the 9 maps and the last stage's
    predicted max (turbo colour map, 0..1), side by side."""
    was_training = model.training
    model.eval()
    with torch.no_grad():
        x = torch.from_numpy(np.ascontiguousarray(crop)).permute(2, 0, 1)[None].float().to(device) / 255.0
        predicted = model(x)[-1][0][0].float().cpu().numpy()
    model.train(was_training)
    size = crop.shape[0]

    def colour(maps):
        heat = np.round(np.clip(maps.max(0), 0, 1) * 255).astype(np.uint8)
        heat = cv2.resize(heat, (size, size), interpolation=cv2.INTER_NEAREST)
        return np.ascontiguousarray(cv2.applyColorMap(heat, cv2.COLORMAP_TURBO)[..., ::-1])

    panels = [crop, colour(target), colour(predicted)]
    for panel, text in zip(panels, ("input", "target beliefs", "predicted beliefs")):
        cv2.putText(panel, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return np.concatenate(panels, axis=1)


def _prepare_output(cfg: TrainConfig, resume: bool) -> dict | None:
    """The checkpoint to resume from (None for a fresh run) after checking the output folder."""
    out = Path(cfg.out)
    stored = out / "train_config.yaml"
    if not resume:
        if not _is_empty(out):
            raise PegasusError(f"{out} is not empty: pass --resume to continue its training or choose another --out")
        return None
    if not (out / "last.pt").is_file():
        raise PegasusError(f"{out}: nothing to resume (no last.pt)")
    state = load_checkpoint(out / "last.pt")
    # a run from before a field existed was trained with its default
    before = {**TrainConfig(data=cfg.data, object=cfg.object).model_dump(mode="json"), **state["train_config"]}
    differ = sorted(k for k, v in cfg.model_dump(mode="json").items() if k not in RESUMABLE_KEYS and before[k] != v)
    if differ:
        raise PegasusError(f"{out} was trained with another configuration ({', '.join(differ)} differ; see {stored})")
    if state["epoch"] >= cfg.epochs:
        raise PegasusError(f"{out} has already trained {state['epoch']} epochs; ask for more with --epochs")
    return state


def loader_workers(cfg: TrainConfig, device: torch.device) -> int:
    """Data loading processes: ``cfg.loader_workers``, or for -1 two on the CPU (the network needs the cores) and
    on CUDA one per CPU core less one, at most 8 (a GPU trains faster than two processes crop and augment)."""
    if cfg.loader_workers >= 0:
        return cfg.loader_workers
    return min(8, max(2, (os.cpu_count() or 2) - 1)) if device.type == "cuda" else 2


def train(cfg: TrainConfig, resume: bool = False) -> Path:
    """Train as ``cfg`` says (see the module docstring); returns the output folder, which is this run's alone
    while it trains (``FolderLock``, taken by rank 0)."""
    rank, world, local_rank = _distributed()
    out = Path(cfg.out)
    with FolderLock(out, "pegasus train") if rank == 0 else contextlib.nullcontext():
        fresh = rank == 0 and not resume and _is_empty(out)
        try:
            return _train(cfg, resume, rank, world, local_rank)
        except BaseException:
            if fresh and not (out / "last.pt").exists():
                _remove_contents(out)  # a fresh run that failed before its first checkpoint leaves nothing
            raise


def _is_empty(folder: Path) -> bool:
    """Whether ``folder`` is missing or holds nothing but a lock file."""
    return not folder.exists() or all(p.name == LOCK_FILE for p in folder.iterdir())


def _remove_contents(folder: Path) -> None:
    """Remove everything in ``folder`` but its lock file (the lock removes that, and the folder if it made it)."""
    for path in folder.iterdir():
        if path.name == LOCK_FILE:
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()


def _train(cfg: TrainConfig, resume: bool, rank: int, world: int, local_rank: int) -> Path:
    device = torch_device(cfg.device, local_rank)
    if world > 1 and not torch.distributed.is_initialized():
        torch.distributed.init_process_group("nccl" if device.type == "cuda" else "gloo")
    if device.type == "cuda":
        torch.cuda.set_device(device)
    state = _prepare_output(cfg, resume)
    out = Path(cfg.out)
    # the held-out share of the photos stays unseen: behind held-out frames it sets the detection score
    photos = split_photos(load_photos(cfg.background_photos))[0] if cfg.backgrounds > 0 else None
    samples, target = load_training_samples(cfg)
    if photos and not any(s.masks for s in samples) and rank == 0:
        print("note: backgrounds needs BOP visible masks (mask_visib), which these data lack: no crop gets a photo")

    torch.manual_seed(cfg.seed)
    architecture = ModelConfig.of(cfg.variant)
    if cfg.batch_norm is not None:
        architecture = replace(architecture, batch_norm=cfg.batch_norm)
    architecture = replace(architecture, distance_head=cfg.distance_head,
                           distance_off_axis=cfg.distance_head and cfg.distance_off_axis,
                           keypoints=cfg.surface_points if cfg.keypoints == "surface" else 8)
    model = DopeNetwork(architecture)
    if state is None and cfg.variant == "full":
        if not load_vgg19_weights(model, cfg.vgg19) and rank == 0:
            print("note: no ImageNet VGG19 weights found (--vgg19 PATH or the torch hub cache): trunk from scratch")
    if state is None and architecture.trunk == "lite0":
        load_pretrained(model.features)
    if cfg.frozen_blocks:
        model.features.freeze(cfg.frozen_blocks)
    check_memory(memory_estimate(architecture, cfg.size, cfg.size, cfg.batch_size, training=True), device,
                 f"training on {cfg.size} px crops in batches of {cfg.batch_size}")
    # channels-last tensors: oneDNN's convolutions (CPU) and cuDNN's under AMP skip their layout conversions
    # (1.2x the images/s of a CPU training step, benchmarks/dope.py); the checkpoint's weights load either way
    model.to(device, memory_format=torch.channels_last)
    optimiser = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=cfg.lr)
    use_amp = cfg.amp and device.type == "cuda"
    scaler = torch.amp.GradScaler("cuda", enabled=use_amp)
    first_epoch, step = 0, 0
    if state is not None:
        model.load_state_dict(state["model"])  # load_checkpoint checked it against the model config
        try:
            optimiser.load_state_dict(state["optimizer"])
            scaler.load_state_dict(state["scaler"])
        except (KeyError, ValueError, TypeError, RuntimeError) as exc:
            raise PegasusError(f"{out / 'last.pt'}: its optimizer/scaler state does not fit the network "
                               f"({type(exc).__name__}: {exc})") from None
        first_epoch, step = state["epoch"], state["step"]
    net = torch.nn.parallel.DistributedDataParallel(model, device_ids=[local_rank] if device.type == "cuda" else None) \
        if world > 1 else model

    dataset = DopeDataset(samples, cfg.size, crop_augment(cfg), seed=cfg.seed, focal_px=cfg.focal_px,
                          sigma_px=cfg.sigma_px, negatives=cfg.negatives, occluders=cfg.occluders,
                          backgrounds=cfg.backgrounds, photos=photos, off_axis=architecture.distance_off_axis)
    # decoded once, before the loader processes fork (they share the memory): half the RAM at most (7,200 frames at
    # 608x456 with masks take 8 GB; read from disk, the CPU step ran at 46 crops/s instead of 61)
    if not dataset.preload(memory_limit(torch.device("cpu")) // (2 * world)) and rank == 0:
        print("note: the training frames do not fit in half the memory: read from disk for every crop")
    sampler = ShardSampler(len(dataset), rank, world, cfg.seed, hidden_weights(samples, cfg.hidden_share))
    workers = loader_workers(cfg, device)  # started once: the sampler's keys carry the epoch to them
    loader = torch.utils.data.DataLoader(dataset, batch_size=cfg.batch_size, sampler=sampler, num_workers=workers,
                                         pin_memory=device.type == "cuda", persistent_workers=workers > 0)
    still = DopeDataset([next(s for s in samples if s.keypoints)], cfg.size, Augment(enabled=False),
                        focal_px=cfg.focal_px, sigma_px=cfg.sigma_px)
    snapshot_crop = still.item(0)[0]
    snapshot_target = still[0][1].numpy()

    rows = []
    if rank == 0:
        (out / "beliefs").mkdir(parents=True, exist_ok=True)
        config_text = yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False).encode()
        write_atomic(out / "train_config.yaml", lambda f: f.write(config_text))
        rows = [r for r in read_losses(out / "loss.csv") if r["step"] <= step] if state else []
        _write_losses(out / "loss.csv", rows)
        print(f"training DOPE-{cfg.variant} on {len(dataset)} images of {target.name!r} (obj_id {target.obj_id}), "
              f"{cfg.size} px crops, batch {cfg.batch_size} x {world} rank(s), {device.type}"
              f"{' with AMP' if use_amp else ''}; epochs {first_epoch + 1}..{cfg.epochs}; output {out}")
    per_epoch = math.ceil(len(dataset) / world / cfg.batch_size)
    bar = tqdm(total=(cfg.epochs - first_epoch) * len(dataset), unit="img", disable=rank != 0, dynamic_ncols=True)
    model.train()
    saved_at = -math.inf  # the first epoch is kept whatever its length: a run that fails later can resume
    for epoch in range(first_epoch, cfg.epochs):
        sampler.set_epoch(epoch)
        join = net.join() if world > 1 else contextlib.nullcontext()
        with join:
            t0 = time.perf_counter()
            for batch, tensors in enumerate(loader):
                image, beliefs, affinities, distance, weight = (t.to(device, non_blocking=True) for t in tensors)
                image = image.contiguous(memory_format=torch.channels_last)
                with torch.autocast(device.type, dtype=torch.float16, enabled=use_amp):
                    outputs = net(image, distance_grad=cfg.distance_grad)
                loss = dope_loss([tuple(t.float() for t in stage) for stage in outputs], beliefs, affinities,
                                 cfg.peak_weight, distance, weight)
                optimiser.zero_grad(set_to_none=True)
                scaler.scale(loss).backward()
                lr = learning_rate(cfg, step, per_epoch * cfg.epochs)
                for group in optimiser.param_groups:
                    group["lr"] = lr
                scaler.step(optimiser)
                scaler.update()
                counts = torch.tensor([loss.item() * len(image), float(len(image))], dtype=torch.float64)
                if world > 1:
                    torch.distributed.all_reduce(counts)
                if not math.isfinite(counts[0].item()):  # every rank sees the same sum and stops
                    bar.close()
                    raise PegasusError(f"training loss became {counts[0].item() / counts[1].item()} at step {step + 1} "
                                       f"(epoch {epoch + 1}): the learning rate ({lr:g}) may be too high or the data "
                                       "hold bad values; stopped (checkpoints of earlier epochs are kept)")
                step += 1
                now = time.perf_counter()
                rate, t0 = counts[1].item() / max(now - t0, 1e-9), now  # loading included
                bar.update(int(counts[1].item()))
                bar.set_postfix(epoch=f"{epoch + 1}/{cfg.epochs}", step=f"{batch + 1}/{per_epoch}",
                                loss=f"{counts[0].item() / counts[1].item():.4g}")
                rows.append({"step": step, "epoch": epoch, "loss": counts[0].item() / counts[1].item(),
                             "images": counts[1].item(), "images_per_s": rate, "lr": lr})
        due = (epoch + 1) % cfg.checkpoint_every == 0 and time.monotonic() - saved_at >= 60 * cfg.checkpoint_minutes
        if rank == 0 and (due or epoch + 1 == cfg.epochs):
            saved_at = time.monotonic()
            _write_losses(out / "loss.csv", rows)
            images.write_image(out / "loss.png", loss_curve(rows))
            images.write_image(out / "beliefs" / f"epoch_{epoch + 1:04d}.png",
                               belief_snapshot(model, snapshot_crop.copy(), snapshot_target, device))
            checkpoint = {"format": CHECKPOINT_FORMAT, "model": model.state_dict(), "optimizer": optimiser.state_dict(),
                          "scaler": scaler.state_dict(), "epoch": epoch + 1, "step": step,
                          "model_config": model_config(model), "train_config": cfg.model_dump(mode="json"),
                          "object": asdict(target), "stride": dataset.stride}
            saved = write_atomic(out / f"epoch_{epoch + 1:04d}.pt", lambda f: torch.save(checkpoint, f))
            link_atomic(saved, out / "last.pt")  # the same file: a full network's checkpoint is ~600 MB
            for old in sorted(out.glob("epoch_*.pt"))[:-cfg.keep_checkpoints]:
                old.unlink()
        if world > 1:
            torch.distributed.barrier()
    bar.close()
    if world > 1:
        torch.distributed.destroy_process_group()
    return out

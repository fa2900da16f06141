"""Training the zoomed second look (``dope_training.zoom``) for one object on BOP datasets (``pegasus train-zoom``).

Each visible instance of the object is seen from ``per_instance`` estimates drawn around its true pose (the box
centre moved aside and along its ray, the rotation turned: the kind of error DOPE makes), and the network learns
the offsets back to the truth (``zoom.offsets``: the position's, and with ``rotation`` the turn's too), or with the
outline ``look`` where the object lies in the crop (``outline.outline_target``: a per-pixel cross-entropy). The crops
are drawn once; every epoch redraws their augmentation: a real photograph behind the objects (BOP's visible masks),
with ``occluders`` part of the object hidden (``occluded``), blur, colour jitter and hue as DOPE's recipe.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
import torch
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from dope_training.backgrounds import (
    behind_objects,
    load_photos,
    masks_union,
    photo_view,
    split_photos,
    warp_alpha,
)
from dope_training.data import Augment, jitter_colour, occluder_mask, resolve_objects
from dope_training.model import torch_device
from dope_training.outline import OutlineNet, crop_tensor, outline_target
from dope_training.refine_rgb import decimated
from dope_training.zoom import (
    OFFSET_STD,
    POSITION,
    SURFACE_VIEWS,
    WITH_ROTATION,
    ZoomGeometry,
    ZoomNet,
    offsets,
    save,
    surfaced,
    zoom_input,
    zoom_tensor,
)
from dope_training.zoom_config import ZoomConfig
from pegasus_gen.errors import PegasusError
from pegasus_gen.formats.bop import bop_frames, mask_name, model_boxes, models_info, object_names, read_model
from pegasus_gen.io.images import read_rgb

# centre x, y, log distance (what DOPE gets least right), the turn's rotation vector
LOSS_WEIGHTS = (1.0, 1.0, 2.0, 1.0, 1.0, 1.0)


def drawn_estimate(T: np.ndarray, K: np.ndarray, g: ZoomGeometry, cfg: ZoomConfig,
                   rng: np.random.Generator) -> np.ndarray:
    """An estimate [4, 4] around the instance at T [4, 4] (m) seen with K [3, 3]: its box centre moved aside by
    ``cfg.centre_std`` of the diameter's pixels and along its ray by exp(N(0, ``cfg.distance_std``)) (clipped at
    3 std), turned about the centre by |N(0, ``cfg.rotation_std_deg``)| about a random axis."""
    p = T[:3, :3] @ g.centre + T[:3, 3]
    uv = (K @ p)[:2] / p[2] + rng.normal(0, cfg.centre_std, 2) * g.diameter * K[0, 0] / p[2]
    z = p[2] * np.exp(np.clip(rng.normal(0, cfg.distance_std), -3 * cfg.distance_std, 3 * cfg.distance_std))
    axis = rng.normal(size=3)
    turn = Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.radians(abs(rng.normal(0, cfg.rotation_std_deg))))
    out = np.eye(4)
    out[:3, :3] = turn.as_matrix() @ T[:3, :3]
    out[:3, 3] = np.linalg.solve(K, [uv[0], uv[1], 1.0]) * z - out[:3, :3] @ g.centre
    return out


def object_geometry(root: Path, obj_id: int, crop_px: int, object_px: float,
                    view: str = "silhouette") -> ZoomGeometry:
    """The ZoomGeometry of ``obj_id`` from a BOP dataset's model and models_info.json for the zoom ``view``: the
    SURFACE_VIEWS' ray caster, and the ``colour`` view's vertex colours of the model (each decimated vertex takes its
    nearest vertex's), a PegasusError when it has none."""
    diameter = models_info(root)[obj_id].diameter
    if diameter is None:
        raise PegasusError(f"{root}: models_info.json gives obj_id {obj_id} no diameter")
    mesh = read_model(root, obj_id)
    vertices, faces = decimated(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    bbox_min, bbox_size = model_boxes(root)[obj_id]
    g = ZoomGeometry(vertices, faces, bbox_min + bbox_size / 2, diameter, crop_px, object_px)
    if view not in SURFACE_VIEWS:
        return g
    if view == "normals":
        return surfaced(g)
    if mesh.visual.kind != "vertex":
        raise PegasusError(f"{root}: the model of obj_id {obj_id} has no vertex colours for the colour view "
                           f"(the silhouette and normals views need none)")
    nearest = cKDTree(np.asarray(mesh.vertices)).query(vertices)[1]
    return surfaced(g, np.asarray(mesh.visual.vertex_colors)[nearest, :3] / 255.0)


def occluded(crop: np.ndarray, view: np.ndarray, other: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``crop`` [C, C, 3] uint8 with a cut-out of ``other`` [C, C, 3] uint8, another crop moved by half its size
    (what lies beside its object), in front of part of this one: ``occluder_mask``'s shape on the box of the
    model's silhouette at the estimate (channel 0 of ``view`` [C, C, V]) grown 1-2 times about its centre, so that
    it may hide a side or most of the object. The targets stay the truth's: the network learns to place an object
    from the part that shows."""
    size = len(crop)
    ys, xs = np.nonzero(view[..., 0])
    box = np.array([xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]) if len(xs) else np.array([0, 0, size, size])
    middle, half = (box[:2] + box[2:]) / 2, (box[2:] - box[:2]) / 2 * rng.uniform(1.0, 2.0)
    mask = occluder_mask(size, np.concatenate([middle - half, middle + half]), rng)
    out = crop.copy()
    out[mask] = np.roll(other, (size // 2, size // 2), axis=(0, 1))[mask]
    return out


def _visible_mask(frame, inst) -> np.ndarray:
    """[H, W] bool: the instance's visible mask (``mask_visib``); a PegasusError when it is not on disk."""
    path = frame.scene / "mask_visib" / mask_name(frame.im_id, inst.index)
    mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if mask is None:
        raise PegasusError(f"{path}: no visible mask to teach the outline look from")
    return mask > 0


def zoom_samples(roots: list[Path], obj_id: int, g: ZoomGeometry, cfg: ZoomConfig, rng: np.random.Generator) -> dict:
    """The drawn crops of every visible instance: crops [N, C, C, 3], the model's views at the estimates [N, C, C, V]
    (``zoom_input``), the objects' visible masks in the crop [N, C, C] (uint8 coverage x 255, for photo
    backgrounds), offsets [N, 6] and for the outline look its targets [N, C, C] (``outline_target`` x 255,
    uint8)."""
    frames = [f for root in roots for f in bop_frames(root / cfg.split)]
    out = {"crops": [], "views": [], "objects": [], "offsets": [], **({"targets": []} if cfg.look == "outline" else {})}
    for frame in tqdm(frames, desc="zoom crops", unit="img"):
        mine = [i for i in frame.instances if i.obj_id == obj_id
                and (1.0 if i.visib_fract is None else i.visib_fract) >= cfg.min_visibility]
        if not mine:
            continue
        image, union = read_rgb(frame.image), masks_union(frame.visible_masks())
        for inst in mine:
            visible = _visible_mask(frame, inst) if cfg.look == "outline" else None
            for _ in range(cfg.per_instance):
                T = drawn_estimate(inst.T, frame.K, g, cfg, rng)
                crop, view, w = zoom_input(image, T, frame.K, g, cfg.view)
                objects = np.rint(255 * warp_alpha(union, w.A, g.crop_px))
                out["crops"].append(crop)
                out["views"].append(view)
                out["objects"].append(objects.astype(np.uint8))
                out["offsets"].append(offsets(inst.T, T, frame.K, g))
                if visible is not None:
                    target = outline_target(inst.T, visible, w.A, w.K, g)
                    out["targets"].append(np.rint(255 * target).astype(np.uint8))
    if not out["crops"]:
        raise PegasusError(f"{', '.join(map(str, roots))}: no instance of obj_id {obj_id} seen at least "
                           f"{cfg.min_visibility:g} in {cfg.split}/")
    return {k: np.stack(v) for k, v in out.items()}


def train_zoom(cfg: ZoomConfig) -> Path:
    """Train the zoom network of ``cfg`` and write its checkpoint to ``cfg.out`` (written when training ends:
    a file there is a finished run); the path."""
    out = Path(cfg.out)
    roots = [Path(d) for d in cfg.data]
    for root in roots:
        if not (root / cfg.split).is_dir():
            raise PegasusError(f"{root}: no {cfg.split}/ folder, so not a BOP dataset to train on")
    names = object_names(roots[0])
    obj_id = resolve_objects([cfg.object], model_boxes(roots[0]), names, str(roots[0]))[0]
    name = next((n for n, k in names.items() if k == obj_id), f"obj_{obj_id:06d}")
    if cfg.look == "outline" and (cfg.rotation or cfg.view != "silhouette"):
        raise PegasusError("the outline look fits the whole pose and reads the crop alone: rotation and view are "
                           "the offsets look's")
    device = torch_device(cfg.device)
    g = object_geometry(roots[0], obj_id, cfg.crop_px, cfg.object_px, cfg.view)
    rng = np.random.default_rng(cfg.seed)
    torch.manual_seed(cfg.seed)
    samples = zoom_samples(roots, obj_id, g, cfg, rng)
    photos = split_photos(load_photos(cfg.background_photos))[0] if cfg.backgrounds > 0 else []
    aug = Augment(blur_px=cfg.blur_px, brightness=cfg.colour_jitter, contrast=cfg.colour_jitter,
                  saturation=cfg.colour_jitter, hue_deg=cfg.hue_deg)
    outputs = WITH_ROTATION if cfg.rotation else POSITION
    net = OutlineNet() if cfg.look == "outline" else ZoomNet(cfg.crop_px, outputs, view=cfg.view)
    net = net.to(device, memory_format=torch.channels_last)
    n = len(samples["crops"])
    batches = max(n // cfg.batch_size, 1)
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=1e-4)
    schedule = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=cfg.lr, total_steps=cfg.epochs * batches,
                                                   pct_start=0.05)
    weights = torch.tensor(LOSS_WEIGHTS[:outputs], device=device)
    scale = torch.from_numpy(OFFSET_STD[:outputs]).to(device)
    started = time.perf_counter()
    net.train()
    for epoch in range(cfg.epochs):
        order = rng.permutation(n)
        total = 0.0
        bar = tqdm(range(batches), desc=f"zoom epoch {epoch + 1}/{cfg.epochs}", unit="batch")
        for b in bar:
            idx = order[b * cfg.batch_size:(b + 1) * cfg.batch_size]
            crops = []
            for i in idx:
                crop = samples["crops"][i]
                if photos and rng.uniform() < cfg.backgrounds:
                    crop = behind_objects(crop, samples["objects"][i] / 255.0, photo_view(photos, cfg.crop_px, rng))
                if cfg.occluders > 0 and n > 1 and rng.uniform() < cfg.occluders:
                    crop = occluded(crop, samples["views"][i], samples["crops"][(i + rng.integers(1, n)) % n], rng)
                crops.append(jitter_colour(crop, rng, aug))
            if cfg.look == "outline":
                y = torch.from_numpy(samples["targets"][idx]).to(device).float() / 255.0
                loss = torch.nn.functional.binary_cross_entropy_with_logits(net(crop_tensor(np.stack(crops)).to(
                    device)), y)
            else:
                x = zoom_tensor(np.stack(crops), samples["views"][idx]).to(device)
                y = torch.from_numpy(samples["offsets"][idx, :outputs]).to(device) / scale
                loss = (torch.nn.functional.smooth_l1_loss(net(x), y, reduction="none") * weights).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            schedule.step()
            total += loss.item()
            bar.set_postfix(loss=f"{total / (b + 1):.4f}")
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(out.name + ".partial")
    save(partial, net.cpu(), g, obj_id, name, {**cfg.model_dump(), "samples": n,
                                               "minutes": round((time.perf_counter() - started) / 60, 1)})
    partial.replace(out)
    return out

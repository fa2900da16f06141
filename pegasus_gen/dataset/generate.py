"""`pegasus generate`: environments + objects (+ unlabelled distractors) -> physics -> camera trajectories ->
appearance and contact shadows on the splats -> renders -> the camera's effects -> BOP dataset.

Layout (BOP train_pbr style)::

    OUTPUT/camera.json  models/obj_XXXXXX.ply  models/models_info.json  models_eval/ (the same, resampled)
    OUTPUT/SPLIT/SSSSSS/{rgb,depth,mask,mask_visib}/...  scene_camera.json scene_gt.json scene_gt_info.json

    OUTPUT/SPLIT/SSSSSS/scene_gt_coco.json  (and rgb/IIIIII.json, DOPE/NDDS, with ``dope_json``)
    OUTPUT/pegasus_config.yaml  (the config the dataset was made with, so the scenes it holds when complete,
                                 and its assets' SHA-256; written before the first scene)
    OUTPUT/.lock  (while a run writes the dataset: a second writer is refused)
    OUTPUT/test_targets_bop19.json  (split test only)

SPLIT is ``train_pbr`` (default), ``val`` or ``test``.

Every scene is built by ``dataset.scene`` in a hidden temporary folder and renamed into place when complete,
so a killed run never leaves a half scene; ``resume`` skips the scenes already there after checking that the
stored config and the assets' files match. Each scene draws from its own random generators seeded by (seed,
scene id): the same seed gives the same annotations whatever was resumed and however many workers ran. Scenes
run in this process, spread over ``workers`` processes, which die with the run (even a kill -9 of it), or as
Ray tasks (``ray``): ``dataset.pools``.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import yaml
from tqdm import tqdm

from pegasus_gen.assets.library import SURFACE, AssetLibrary
from pegasus_gen.dataset.config import CONFIG_FILE, GenerateConfig
from pegasus_gen.dataset.models import cached_eval_model, symmetry_fields, write_model_ply
from pegasus_gen.dataset.pools import build_in_processes, build_on_ray, ray_session
from pegasus_gen.dataset.scene import Assets, build_scene, camera_matrix, load_assets, write_json
from pegasus_gen.errors import PegasusError
from pegasus_gen.formats import bop
from pegasus_gen.io.files import parse_yaml, write_atomic
from pegasus_gen.io.lock import LOCK_FILE, FolderLock
from pegasus_gen.render.renderer import check_image_memory

# random streams of a scene besides its plan's (seeded [seed, scene_id]): [seed, scene_id, stream, ...], so
# config keys that may differ between a dataset and a run resuming it (they change no annotation)
RESUMABLE_KEYS = ("output", "library", "device", "workers", "ray")
MODELS_CACHE = ".cache/models_eval"  # in the asset library: evaluation models by surface content (dataset.models)


def write_models(out: Path, assets: Assets, cfg: GenerateConfig) -> None:
    """models/ (each object's surface: PLY in mm with colours, bbox-centred object frames), models_eval/ (the
    surfaces resampled as BOP's, cached in the library's MODELS_CACHE), their models_info.json, and
    camera.json."""
    info, info_eval = {}, {}
    cache = AssetLibrary(cfg.library).root / MODELS_CACHE
    for obj_id, asset in sorted(assets.objects.items()):
        name = f"obj_{obj_id:06d}.ply"
        write_model_ply(out / "models" / name, asset.surface)
        eval_ply, extent, extent_eval = cached_eval_model(asset.path / SURFACE, asset.surface, cache)
        write_atomic(out / "models_eval" / name, lambda f, data=eval_ply: f.write(data))
        symmetries = symmetry_fields(asset.manifest.symmetries_discrete, asset.manifest.symmetries_continuous)
        info[str(obj_id)] = {**extent, **symmetries, "name": asset.name}
        info_eval[str(obj_id)] = {**extent_eval, **symmetries, "name": asset.name}
    write_json(out / "models" / "models_info.json", info)
    write_json(out / "models_eval" / "models_info.json", info_eval)
    K = camera_matrix(cfg)
    write_json(out / "camera.json", {"cx": K[0, 2], "cy": K[1, 2], "depth_scale": cfg.depth_scale,
                                      "fx": K[0, 0], "fy": K[1, 1], "height": cfg.camera.height,
                                      "width": cfg.camera.width})


def asset_fingerprints(assets: Assets) -> dict[str, str]:
    """{asset name: SHA-256 of its files} of every asset a dataset is made from (a resume refuses when one
    changed: its scenes would not match the ones already written)."""
    out = {}
    for asset in [*assets.environments, *assets.per_spec]:
        digest = hashlib.sha256()
        for path in sorted(p for p in asset.path.iterdir() if p.is_file()):
            digest.update(path.name.encode() + b"\0" + path.read_bytes())
        out[asset.name] = digest.hexdigest()
    return out


def _stored_config(cfg: GenerateConfig, assets: Assets) -> dict:
    data = cfg.model_dump(mode="json")
    for key in RESUMABLE_KEYS:
        data.pop(key, None)
    data["asset_sha256"] = asset_fingerprints(assets)
    return data


def _differences(a, b, prefix="") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        return [d for k in sorted(set(a) | set(b)) for d in _differences(a.get(k), b.get(k), f"{prefix}{k}.")]
    return [prefix.rstrip(".")] if a != b else []


def check_output(out: Path, resume: bool) -> None:
    """Refuse to mix datasets, on what the folder alone shows: a non-empty ``out`` needs ``resume`` and a
    CONFIG_FILE (a dataset made by pegasus generate). Checked before the lock is taken (a refused run leaves
    nothing behind) and again under it."""
    if not out.is_dir() or not any(p.name != LOCK_FILE for p in out.iterdir()):
        return
    if not resume:
        raise PegasusError(f"{out} is not empty; pass --resume to continue the dataset there, or choose another output")
    if not (out / CONFIG_FILE).is_file():
        raise PegasusError(f"{out}: no {CONFIG_FILE}, so this is not a dataset made by pegasus generate; "
                           "choose another output")


def prepare_output(out: Path, cfg: GenerateConfig, assets: Assets, resume: bool) -> None:
    """Under the output's lock: ``check_output``, then a resume needs the config the dataset was made with
    (keys in RESUMABLE_KEYS excepted) and the same asset files. Records the config (the scenes it holds when
    complete among it) and the assets' fingerprints in a new dataset."""
    check_output(out, resume)
    record = out / CONFIG_FILE
    if record.is_file():
        stored = parse_yaml(record.read_text(errors="replace"), f"{record} (so this dataset cannot be resumed)")
        if not isinstance(stored, dict):
            raise PegasusError(f"{record}: not a generate config (a YAML mapping); this dataset cannot be resumed")
        changed = _differences(stored, _stored_config(cfg, assets))
        if changed:
            raise PegasusError(f"{out} was made with a different config or assets ({', '.join(changed)} differ); "
                               "resume with the same ones or choose another output")
        return
    write_atomic(record, lambda f: f.write(yaml.safe_dump(_stored_config(cfg, assets), sort_keys=True).encode()))


def generate(cfg: GenerateConfig, resume: bool = False) -> Path:
    """Write the dataset described by ``cfg``; returns the output folder. With ``resume`` the scenes
    already in a matching dataset are kept and only the missing ones are made."""
    check_image_memory(cfg.camera.width, cfg.camera.height)  # all checks before the output folder is touched
    assets = load_assets(cfg)
    out = Path(cfg.output)
    check_output(out, resume)
    with ray_session(cfg.ray, cfg.workers), FolderLock(out, "pegasus generate"):
        prepare_output(out, cfg, assets, resume)
        return _generate(out, cfg, assets)


def _generate(out: Path, cfg: GenerateConfig, assets: Assets) -> Path:
    split = out / cfg.split
    split.mkdir(exist_ok=True)
    write_models(out, assets, cfg)
    todo = [s for s in range(cfg.scenes) if not (split / f"{s:06d}").is_dir()]
    with tqdm(total=len(todo) * cfg.frames_per_scene, desc="generate", unit="frame", smoothing=0.1) as bar:
        if cfg.ray is not None:
            build_on_ray(split, todo, cfg, assets, bar)
        elif cfg.workers > 1 and len(todo) > 1:
            build_in_processes(split, todo, cfg, bar)
        else:
            for scene_id in todo:
                build_scene(split, scene_id, cfg, assets, lambda: bar.update(1))
    if cfg.split == "test":
        write_json(out / "test_targets_bop19.json", bop.targets_bop19(split))
    return out

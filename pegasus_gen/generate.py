"""`pegasus generate`: environments + objects -> physics -> camera trajectories -> renders -> BOP dataset.

Layout (BOP train_pbr style)::

    OUTPUT/camera.json  models/obj_XXXXXX.ply  models/models_info.json
    OUTPUT/train_pbr/SSSSSS/{rgb,depth,mask,mask_visib}/...  scene_camera.json scene_gt.json scene_gt_info.json

Every scene is built in a hidden temporary folder and renamed into place when complete, so a killed
run never leaves a half scene; a rerun skips the scenes already there (``resume``). Each scene draws
from its own random generator seeded by (seed, scene id): the same seed gives the same annotations
whatever was resumed.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pegasus_gen import bop
from pegasus_gen.assets import Asset, AssetLibrary
from pegasus_gen.cameras import interpolate_poses, intrinsics, orbit_key_poses
from pegasus_gen.config import GenerateConfig
from pegasus_gen.errors import PegasusError
from pegasus_gen.files import write_atomic
from pegasus_gen.images import rgb_to_uint8, write_image
from pegasus_gen.physics import DropResult, drop_objects
from pegasus_gen.render import render

SPLIT = "train_pbr"


def camera_matrix(cfg: GenerateConfig) -> np.ndarray:
    """K [3, 3] from the camera config (fx/fy when given, else the field of view)."""
    c = cfg.camera
    return intrinsics(c.width, c.height, c.fov_deg, c.fx, c.fy, c.cx, c.cy)


@dataclass
class Assets:
    environments: list[Asset]
    per_spec: list[Asset]  # the object asset of each entry of cfg.objects, in order

    @property
    def objects(self) -> dict[int, Asset]:
        """The distinct object assets by obj_id."""
        return {a.manifest.obj_id: a for a in self.per_spec}


def load_assets(cfg: GenerateConfig) -> Assets:
    """Every asset the config names, loaded and checked before anything is written."""
    lib = AssetLibrary(cfg.library)
    envs = [lib.get(name) for name in cfg.environments]
    for env in envs:
        if env.manifest.kind != "environment":
            raise PegasusError(f"config environments: {env.name} is not an environment asset")
    per_spec = [lib.get(spec.asset) for spec in cfg.objects]
    for asset in per_spec:
        if asset.manifest.kind != "object":
            raise PegasusError(f"config objects: {asset.name} is not an object asset")
    return Assets(envs, per_spec)


def write_models(out: Path, assets: Assets, cfg: GenerateConfig) -> None:
    """models/ (PLY in mm, bbox-centred object frames), models_info.json and camera.json."""
    models = out / "models"
    info = {}
    for obj_id, asset in sorted(assets.objects.items()):
        bop.write_model_ply(models / f"obj_{obj_id:06d}.ply", asset.mesh)
        info[str(obj_id)] = bop.models_info_entry(asset.mesh, asset.manifest.symmetries_discrete,
                                                  asset.manifest.symmetries_continuous)
    _write_json(models / "models_info.json", info)
    K = camera_matrix(cfg)
    _write_json(out / "camera.json", {"cx": K[0, 2], "cy": K[1, 2], "depth_scale": cfg.depth_scale,
                                      "fx": K[0, 0], "fy": K[1, 1], "height": cfg.camera.height,
                                      "width": cfg.camera.width})


def _write_json(path: Path, data) -> None:
    write_atomic(path, lambda f: f.write((json.dumps(data, indent=2) + "\n").encode()))


def _choose_objects(cfg: GenerateConfig, assets: Assets, rng: np.random.Generator) -> list[Asset]:
    chosen = []
    for spec, asset in zip(cfg.objects, assets.per_spec):
        chosen += [asset] * int(rng.integers(spec.count[0], spec.count[1] + 1))
    while len(chosen) < cfg.min_objects:
        chosen.append(assets.per_spec[int(rng.integers(len(assets.per_spec)))])
    return chosen


@dataclass
class ScenePlan:
    """What a scene holds: its environment, the objects dropped (by instance index), the physics
    result (rest poses, and for dynamic scenes the poses at each camera frame), and the RNG to go on with."""

    environment: Asset
    objects: list[Asset]
    drop: DropResult
    rng: np.random.Generator


def plan_scene(scene_id: int, cfg: GenerateConfig, assets: Assets) -> ScenePlan:
    """Choose and simulate scene ``scene_id``; deterministic in (cfg.seed, scene_id)."""
    rng = np.random.default_rng([cfg.seed, scene_id])
    env = assets.environments[int(rng.integers(len(assets.environments)))]
    objects = _choose_objects(cfg, assets, rng)
    drop = drop_objects(env, objects, rng, record_fps=cfg.fps if cfg.dynamic else None)
    return ScenePlan(env, objects, drop, rng)


def frame_poses(plan: ScenePlan, im_id: int, dynamic: bool) -> dict[int, np.ndarray]:
    """T_world_obj per kept instance at frame ``im_id``: the recorded motion in dynamic scenes (then the
    rest poses once the motion has ended), the rest poses in static ones."""
    kept = sorted(plan.drop.poses)
    if dynamic and im_id < len(plan.drop.trajectory):
        frame = plan.drop.trajectory[im_id][1]
        return {i: frame[i] for i in kept}
    return {i: plan.drop.poses[i] for i in kept}


CANVAS_MARGIN = 8  # px around an object's projected mesh box: its splats reach a little beyond the mesh


def object_depth_canvas(splats, mesh, T_cam_obj: np.ndarray, K_canvas: np.ndarray, T_cam_world: np.ndarray,
                        width: int, height: int, device: str) -> np.ndarray:
    """[3H, 3W] z-depth (m) of one placed object rendered alone on the 3x canvas of calc_gt_info.

    Only the window around the object's projected mesh box is rendered (the rest of the canvas is
    empty anyway), which makes this ~10x cheaper than rendering the whole canvas.
    """
    canvas = np.zeros((3 * height, 3 * width), np.float32)
    pts = np.asarray(mesh.vertices) @ T_cam_obj[:3, :3].T + T_cam_obj[:3, 3]
    if (pts[:, 2] <= 0.01).any():  # partly behind the camera: render the whole canvas
        x0, y0, x1, y1 = 0, 0, 3 * width, 3 * height
    else:
        uv = pts[:, :2] / pts[:, 2:3] * [K_canvas[0, 0], K_canvas[1, 1]] + [K_canvas[0, 2], K_canvas[1, 2]]
        x0, y0 = np.maximum(np.floor(uv.min(0)).astype(int) - CANVAS_MARGIN, 0)
        x1 = min(int(np.ceil(uv[:, 0].max())) + CANVAS_MARGIN + 1, 3 * width)
        y1 = min(int(np.ceil(uv[:, 1].max())) + CANVAS_MARGIN + 1, 3 * height)
        if x0 >= x1 or y0 >= y1:
            return canvas
    K_window = K_canvas.copy()
    K_window[0, 2] -= x0
    K_window[1, 2] -= y0
    canvas[y0:y1, x0:x1] = render(splats, K_window, T_cam_world, x1 - x0, y1 - y0, device=device).depth
    return canvas


def render_scene(scene_dir: Path, scene_id: int, cfg: GenerateConfig, assets: Assets) -> None:
    """Simulate, render and write one scene into ``scene_dir`` (a fresh folder)."""
    plan = plan_scene(scene_id, cfg, assets)
    env, objects, drop, rng = plan.environment, plan.objects, plan.drop, plan.rng
    kept = sorted(drop.poses)
    if not kept:
        raise PegasusError(f"scene {scene_id}: every object left the support of {env.name}")
    centre = np.mean([drop.poses[i][:3, 3] for i in kept], axis=0)
    keys = orbit_key_poses(centre, rng, cfg.trajectory.key_poses, cfg.trajectory.distance,
                           cfg.trajectory.elevation_deg, cfg.trajectory.azimuth_span_deg, cfg.trajectory.jitter)
    cams = interpolate_poses(keys, cfg.frames_per_scene)
    K = camera_matrix(cfg)
    W, H = cfg.camera.width, cfg.camera.height
    K_canvas = K.copy()
    K_canvas[0, 2] += W
    K_canvas[1, 2] += H
    for sub in ("rgb", "depth", "mask", "mask_visib"):
        (scene_dir / sub).mkdir(parents=True)
    scene_gt, scene_camera, scene_info = {}, {}, {}
    placed = None
    for im_id, T_cam_world in enumerate(cams):
        poses = frame_poses(plan, im_id, cfg.dynamic)
        if placed is None or cfg.dynamic:  # static scenes place their objects once
            placed = [objects[i].splats.transformed(poses[i]).with_label(n + 1) for n, i in enumerate(kept)]
        out = render([env.splats, *placed], K, T_cam_world, W, H, device=cfg.device)
        write_image(scene_dir / "rgb" / f"{im_id:06d}.{cfg.image_format}", rgb_to_uint8(out.rgb), jpg_quality=cfg.jpg_quality)
        write_image(scene_dir / "depth" / f"{im_id:06d}.png", bop.depth_to_png_values(out.depth, cfg.depth_scale))
        scene_camera[str(im_id)] = bop.camera_entry(K, T_cam_world, cfg.depth_scale)
        gts, infos = [], []
        for gt_idx, i in enumerate(kept):
            T_cam_obj = T_cam_world @ poses[i]
            canvas = object_depth_canvas(placed[gt_idx], objects[i].mesh, T_cam_obj, K_canvas, T_cam_world, W, H,
                                         cfg.device)
            info, mask, visible = bop.gt_info_entry(canvas, out.depth, K, cfg.visib_delta)
            write_image(scene_dir / "mask" / f"{im_id:06d}_{gt_idx:06d}.png", mask.astype(np.uint8) * 255)
            write_image(scene_dir / "mask_visib" / f"{im_id:06d}_{gt_idx:06d}.png", visible.astype(np.uint8) * 255)
            gts.append(bop.pose_entry(T_cam_obj, objects[i].manifest.obj_id))
            infos.append(info)
        scene_gt[str(im_id)] = gts
        scene_info[str(im_id)] = infos
    _write_json(scene_dir / "scene_gt.json", scene_gt)
    _write_json(scene_dir / "scene_camera.json", scene_camera)
    _write_json(scene_dir / "scene_gt_info.json", scene_info)


def generate(cfg: GenerateConfig) -> Path:
    """Write the dataset described by ``cfg``; returns the output folder. Scenes already there are kept."""
    assets = load_assets(cfg)  # all checks before the output folder is touched
    out = Path(cfg.output)
    split = out / SPLIT
    split.mkdir(parents=True, exist_ok=True)
    write_models(out, assets, cfg)
    todo = [s for s in range(cfg.scenes) if not (split / f"{s:06d}").is_dir()]
    frames = tqdm(total=len(todo) * cfg.frames_per_scene, desc="generate", unit="frame")
    for scene_id in todo:
        final = split / f"{scene_id:06d}"
        tmp = split / f".{scene_id:06d}.tmp"
        shutil.rmtree(tmp, ignore_errors=True)  # left over by a killed run
        try:
            render_scene(tmp, scene_id, cfg, assets)
            tmp.rename(final)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        frames.update(cfg.frames_per_scene)
    frames.close()
    return out

"""One scene of `pegasus generate`: environments + objects (+ unlabelled distractors) -> physics -> camera
trajectory -> appearance and contact shadows on the splats -> renders -> the camera's effects -> the scene's
BOP files (and COCO, DOPE json), written into a hidden temporary folder and renamed into place when
complete (``build_scene``, the one per-scene entry of a run, its worker processes and its Ray tasks).

Each scene draws from its own random generators seeded by (seed, scene id, stream): the same seed gives the same
annotations whatever was resumed and however many workers ran, and switching shadows or randomisation on
changes no object, pose or camera. Image encoding and writing run on threads while the next frame renders.
"""

from __future__ import annotations

import json
import shutil
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from pegasus_gen.assets.library import Asset, AssetLibrary
from pegasus_gen.dataset.appearance import (
    ObjectLight,
    environment_texture,
    environment_tint,
    frame_effects,
    image_motion,
    object_colour_transforms,
    object_light,
)
from pegasus_gen.dataset.coco import CocoInstance, scene_coco
from pegasus_gen.dataset.config import GenerateConfig
from pegasus_gen.dataset.distractors import Distractor, make_distractor, object_palette
from pegasus_gen.dataset.dope_json import dope_image, dope_object
from pegasus_gen.dataset.physics import DropResult, drop_objects, packed_region, upright_quat_xyzw
from pegasus_gen.dataset.trajectory import camera_trajectory
from pegasus_gen.errors import PegasusError
from pegasus_gen.formats import bop
from pegasus_gen.geometry.cameras import intrinsics
from pegasus_gen.io.files import write_atomic
from pegasus_gen.io.images import rgb_to_uint8, write_image
from pegasus_gen.render.raycast import MeshRaycaster
from pegasus_gen.render.renderer import render
from pegasus_gen.render.sensor import apply_sensor
from pegasus_gen.render.shadows import contact_shadows, occluder
from pegasus_gen.splats.cloud import SplatCloud
from pegasus_gen.splats.colour import (
    blend_colour,
    shade_lambert,
    shade_specular,
    smooth_normals,
    transform_colour,
)

# random streams of a scene besides its plan's (seeded [seed, scene_id]): [seed, scene_id, stream, ...], so
# switching shadows or randomisation on changes no object, pose or camera
(SHADOW_STREAM, APPEARANCE_STREAM, CAMERA_STREAM, DISTRACTOR_STREAM, LIGHT_STREAM, UPRIGHT_STREAM,
 PACKED_STREAM, OCCLUSION_STREAM) = 1, 2, 3, 4, 5, 6, 7, 8



def camera_matrix(cfg: GenerateConfig) -> np.ndarray:
    """K [3, 3] from the camera config (fx/fy when given, else the field of view)."""
    c = cfg.camera
    return intrinsics(c.width, c.height, c.fov_deg, c.fx, c.fy, c.cx, c.cy)


@dataclass
class Assets:
    environments: list[Asset]
    per_spec: list[Asset]  # the object asset of each entry of cfg.objects, in order
    _raycasters: dict = field(default_factory=dict, repr=False)  # obj_id -> MeshRaycaster, built in this process
    _hulls: dict = field(default_factory=dict, repr=False)  # obj_id -> [V, 3] convex hull vertices, ditto
    _normals: dict = field(default_factory=dict, repr=False)  # asset name -> [N, 3] smoothed splat normals, ditto

    @property
    def objects(self) -> dict[int, Asset]:
        """The distinct object assets by obj_id."""
        return {a.manifest.obj_id: a for a in self.per_spec}

    def raycaster(self, obj_id: int) -> MeshRaycaster:
        """The surface model of object ``obj_id`` prepared for ray casting, once per process (not pickled)."""
        if obj_id not in self._raycasters:
            self._raycasters[obj_id] = MeshRaycaster(self.objects[obj_id].surface)
        return self._raycasters[obj_id]

    def hull(self, obj_id: int) -> np.ndarray:
        """[V, 3] the vertices of the convex hull of object ``obj_id``'s surface (m, object frame), once per process:
        few points whose projection bounds the object's as tightly as all of its vertices."""
        if obj_id not in self._hulls:
            self._hulls[obj_id] = np.asarray(self.objects[obj_id].surface.convex_hull.vertices)
        return self._hulls[obj_id]

    def normals(self, obj: Asset | Distractor) -> np.ndarray:
        """[N, 3] unit normals of ``obj``'s splats smoothed over their neighbours (``smooth_normals`` about its
        origin, in its own frame: rotated with the object, since a rigid motion keeps the neighbours), once per
        process for an asset; a distractor's (new in every scene) computed each time."""
        if not isinstance(obj, Asset):
            return smooth_normals(obj.splats, np.zeros(3))
        if obj.name not in self._normals:
            self._normals[obj.name] = smooth_normals(obj.splats, np.zeros(3))
        return self._normals[obj.name]

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_raycasters": {}, "_hulls": {}, "_normals": {}}


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


def write_json(path: Path, data) -> None:
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
    """What a scene holds: its environment, the objects dropped (by instance index: the ``targets`` labelled
    object assets first, then the distractors), the physics result (rest poses, and for dynamic scenes the
    poses at each camera frame), and the RNG to go on with."""

    environment: Asset
    objects: list[Asset | Distractor]
    targets: int
    drop: DropResult
    rng: np.random.Generator

    def labelled(self, indices) -> list[int]:
        """The instance ``indices`` that are targets (labelled), in order."""
        return [i for i in indices if i < self.targets]


DROP_ATTEMPTS = 5  # drops of a scene's objects (new spawn poses each) before a scene without targets is an error


def plan_scene(scene_id: int, cfg: GenerateConfig, assets: Assets) -> ScenePlan:
    """Choose and simulate scene ``scene_id``; deterministic in (cfg.seed, scene_id). When every target
    object falls off the support, they are dropped again from new spawn poses (``DROP_ATTEMPTS`` in all)."""
    rng = np.random.default_rng([cfg.seed, scene_id])
    env = assets.environments[int(rng.integers(len(assets.environments)))]
    objects = _choose_objects(cfg, assets, rng)
    clutter_rng = np.random.default_rng([cfg.seed, scene_id, DISTRACTOR_STREAM])
    count = int(clutter_rng.integers(cfg.distractors.count[0], cfg.distractors.count[1] + 1))
    palette = object_palette([o.splats for o in objects], clutter_rng) if cfg.distractors.object_colours else None
    distractors = [make_distractor(cfg.distractors, clutter_rng, k, palette) for k in range(count)]
    upright_rng = np.random.default_rng([cfg.seed, scene_id, UPRIGHT_STREAM])
    orientations = [upright_quat_xyzw(upright_rng) if upright_rng.random() < cfg.upright else None for _ in objects]
    orientations += [None] * len(distractors)  # distractors fall in a random orientation
    packed_rng = np.random.default_rng([cfg.seed, scene_id, PACKED_STREAM])
    region = (packed_region(env.manifest.drop_region, objects + distractors, packed_rng)
              if packed_rng.random() < cfg.packed else None)
    for _ in range(DROP_ATTEMPTS):  # the same draws as before unless every target fell off
        drop = drop_objects(env, objects + distractors, rng, record_fps=cfg.fps if cfg.dynamic else None,
                            orientations=orientations, region=region)
        if any(i < len(objects) for i in drop.poses):
            break
    return ScenePlan(env, objects + distractors, len(objects), drop, rng)


def frame_poses(plan: ScenePlan, im_id: int, dynamic: bool) -> dict[int, np.ndarray]:
    """T_world_obj per kept instance at frame ``im_id``: the recorded motion in dynamic scenes (then the
    rest poses once the motion has ended), the rest poses in static ones."""
    kept = sorted(plan.drop.poses)
    if dynamic and im_id < len(plan.drop.trajectory):
        frame = plan.drop.trajectory[im_id][1]
        return {i: frame[i] for i in kept}
    return {i: plan.drop.poses[i] for i in kept}


def object_depth_window(model: MeshRaycaster, vertices: np.ndarray, T_cam_obj: np.ndarray, K_canvas: np.ndarray,
                        width: int, height: int) -> bop.CanvasWindow:
    """The z-depth (m) of one placed object's model alone on the 3x canvas of calc_gt_info (0 where it is
    absent): one ray through each pixel centre, as a rasteriser samples them, cast only in the window around the
    projection of the model's vertices (the whole canvas when the model reaches behind the camera).

    ``model`` is the object's surface prepared for ray casting and ``vertices`` [V, 3] points (m, object frame)
    whose hull holds it: its vertices, its convex hull's (the same window, fewer points) or the corners of its
    bounding box (a larger window).
    """
    pts = vertices @ T_cam_obj[:3, :3].T + T_cam_obj[:3, 3]
    if (pts[:, 2] <= 0.01).any():  # partly behind the camera: cast the whole canvas
        x0, y0, x1, y1 = 0, 0, 3 * width, 3 * height
    else:
        uv = pts[:, :2] / pts[:, 2:3] * [K_canvas[0, 0], K_canvas[1, 1]] + [K_canvas[0, 2], K_canvas[1, 2]]
        x0, y0 = np.maximum(np.floor(uv.min(0)).astype(int), 0)
        x1 = min(int(np.ceil(uv[:, 0].max())) + 1, 3 * width)
        y1 = min(int(np.ceil(uv[:, 1].max())) + 1, 3 * height)
        if x0 >= x1 or y0 >= y1:
            return bop.CanvasWindow(np.zeros((0, 0), np.float32))
    K_window = K_canvas.copy()
    K_window[0, 2] -= x0
    K_window[1, 2] -= y0
    return bop.CanvasWindow(model.depth(K_window, T_cam_obj, x1 - x0, y1 - y0), int(x0), int(y0))


@dataclass
class SceneLooks:
    """A scene's colour transforms [3, 3] (the environment's tint and each kept object instance's, in order),
    the texture painted over its environment, if any: (points [N, 3] -> rgb [N, 3], blend weight), and the
    light on its objects, if any."""

    environment: np.ndarray
    objects: list[np.ndarray]
    texture: tuple[Callable, float] | None
    light: ObjectLight | None = None


def scene_looks(cfg: GenerateConfig, scene_id: int, count: int, labelled: list[SplatCloud]) -> SceneLooks | None:
    """The appearance draws of scene ``scene_id`` with ``count`` kept objects, the ``labelled`` ones among them
    given (None without randomisation)."""
    if not cfg.appearance.enabled:
        return None
    rng = np.random.default_rng([cfg.seed, scene_id, APPEARANCE_STREAM])
    return SceneLooks(environment_tint(cfg.appearance, rng), object_colour_transforms(cfg.appearance, count, rng),
                      environment_texture(cfg.appearance, rng, labelled),
                      object_light(cfg.appearance, np.random.default_rng([cfg.seed, scene_id, LIGHT_STREAM])))


def shadowed_scene(cfg: GenerateConfig, scene_id: int) -> bool:
    """Whether scene ``scene_id``'s objects cast contact shadows: ``cfg.shadows.enabled`` and, where its ``share``
    is under 1, a draw of the scene's own (the other draws of the scene stay as they are)."""
    shadows = cfg.shadows
    if not shadows.enabled:
        return False
    return shadows.share >= 1.0 or np.random.default_rng([cfg.seed, scene_id, SHADOW_STREAM]).random() < shadows.share


def place_objects(plan: ScenePlan, poses: dict[int, np.ndarray], cfg: GenerateConfig, looks: SceneLooks | None,
                  rng: np.random.Generator, shadowed: bool) -> tuple[SplatCloud, list[SplatCloud]]:
    """The environment's splats and each kept object's splats placed at ``poses`` (targets labelled 1.. in
    order, distractors 0 as the environment), recoloured by ``looks`` and, where ``shadowed`` (``shadowed_scene``),
    shaded as ``cfg.shadows`` says (``rng``: the shadow rays' spin)."""
    kept = sorted(poses)
    labels = {i: n + 1 for n, i in enumerate(plan.labelled(kept))}
    environment = plan.environment.splats
    placed = [plan.objects[i].splats.transformed(poses[i]).with_label(labels.get(i, 0)) for i in kept]
    if looks is not None:
        if looks.texture is not None:
            texture, weight = looks.texture
            environment = blend_colour(environment, texture(environment.means), weight)
        environment = transform_colour(environment, looks.environment)
        placed = [transform_colour(cloud, M) for cloud, M in zip(placed, looks.objects)]
        if looks.light is not None:
            placed = [shade_lambert(cloud, poses[i][:3, 3], looks.light.direction, looks.light.ambient)
                      for cloud, i in zip(placed, kept)]
    if not shadowed:
        return environment, placed
    meshes = [occluder(plan.objects[i].surface).copy().apply_transform(poses[i]) for i in kept]
    return contact_shadows(environment, placed, meshes, cfg.shadows.params(), rng)


def highlighted(placed: list[SplatCloud], normals: list[np.ndarray] | None, looks: SceneLooks | None,
                T_cam_world: np.ndarray) -> list[SplatCloud]:
    """The placed objects' clouds (``place_objects``) with the scene light's highlights as the camera T_cam_world
    [4, 4] sees them, ``normals`` [N, 3] per cloud (world; ``smooth_normals``); as they are without a light or
    its highlights (``normals`` None)."""
    if normals is None:
        return placed
    eye = -T_cam_world[:3, :3].T @ T_cam_world[:3, 3]
    light = looks.light
    return [shade_specular(cloud, n, light.direction, eye, light.specular, light.shininess)
            for cloud, n in zip(placed, normals)]


def camera_image(rgb: np.ndarray, cfg: GenerateConfig, scene_id: int, im_id: int, K: np.ndarray,
                 cams: list[np.ndarray], centre: np.ndarray) -> tuple[np.ndarray, int]:
    """(the rendered ``rgb`` [H, W, 3] (0..1) as the randomised camera of frame ``im_id`` records it, its JPEG
    quality); the motion blur follows the image motion of ``centre`` [3] (world) between the frame's
    neighbours in ``cams``."""
    if not cfg.appearance.enabled:
        return rgb, cfg.jpg_quality
    before, after = max(im_id - 1, 0), min(im_id + 1, len(cams) - 1)
    motion = image_motion(K, cams[before], cams[after], centre, after - before)
    rng = np.random.default_rng([cfg.seed, scene_id, CAMERA_STREAM, im_id])
    effects, quality = frame_effects(cfg.appearance, rng, motion)
    return apply_sensor(rgb, effects, rng), quality


class _Writer:
    """Encodes and writes images on threads while the caller renders; ``close`` waits and re-raises."""

    def __init__(self, threads: int = 2):
        self.pool = ThreadPoolExecutor(threads)
        self.pending: list[Future] = []

    def image(self, path: Path, image: np.ndarray, jpg_quality: int = 95) -> None:
        self.pending.append(self.pool.submit(write_image, path, image, jpg_quality))

    def close(self) -> None:
        try:
            for f in self.pending:
                f.result()
        finally:
            self.pool.shutdown(wait=True, cancel_futures=True)


def render_scene(scene_dir: Path, scene_id: int, cfg: GenerateConfig, assets: Assets,
                 on_frame: Callable[[], None] = lambda: None) -> None:
    """Simulate, render and write one scene into ``scene_dir`` (a fresh folder); ``on_frame`` after each frame."""
    plan = plan_scene(scene_id, cfg, assets)
    env, objects, drop = plan.environment, plan.objects, plan.drop
    kept = sorted(drop.poses)
    labelled = plan.labelled(kept)
    if not labelled:
        raise PegasusError(f"scene {scene_id}: every object left the support of {env.name} in {DROP_ATTEMPTS} drops "
                           "(a support too small for them?)")
    K = camera_matrix(cfg)
    cams = camera_trajectory(env.mesh, objects, drop.poses, plan.targets, cfg, K, plan.rng,
                             np.random.default_rng([cfg.seed, scene_id, OCCLUSION_STREAM]))
    W, H = cfg.camera.width, cfg.camera.height
    K_canvas = K.copy()
    K_canvas[0, 2] += W
    K_canvas[1, 2] += H
    for sub in ("rgb", "depth", "mask", "mask_visib"):
        (scene_dir / sub).mkdir(parents=True)
    scene_gt, scene_camera, scene_info = {}, {}, {}
    coco_images, coco_instances = [], []
    looks = scene_looks(cfg, scene_id, len(kept), [objects[i].splats for i in labelled])
    shadowed = shadowed_scene(cfg, scene_id)
    environment, placed, normals = None, None, None
    writer = _Writer()
    try:
        for im_id, T_cam_world in enumerate(cams):
            poses = frame_poses(plan, im_id, cfg.dynamic)
            if placed is None or cfg.dynamic:  # static scenes place (and shade) their objects once
                shading_rng = np.random.default_rng([cfg.seed, scene_id, SHADOW_STREAM, im_id])
                environment, placed = place_objects(plan, poses, cfg, looks, shading_rng, shadowed)
                normals = None
                if looks is not None and looks.light is not None and looks.light.specular > 0:
                    normals = [assets.normals(objects[i]) @ poses[i][:3, :3].T for i in kept]
            shown = highlighted(placed, normals, looks, T_cam_world)
            out = render([environment, *shown], K, T_cam_world, W, H, device=cfg.device, antialiased=cfg.antialiased)
            centre = np.mean([poses[i][:3, 3] for i in kept], axis=0)
            rgb, quality = camera_image(out.rgb, cfg, scene_id, im_id, K, cams, centre)
            rgb_name = f"rgb/{im_id:06d}.{cfg.image_format}"
            writer.image(scene_dir / rgb_name, rgb_to_uint8(rgb), quality)
            writer.image(scene_dir / "depth" / f"{im_id:06d}.png", bop.depth_to_png_values(out.depth, cfg.depth_scale))
            scene_camera[str(im_id)] = bop.camera_entry(K, T_cam_world, cfg.depth_scale)
            coco_images.append({"id": im_id, "file_name": rgb_name, "width": W, "height": H})
            gts, infos, dope_objects = [], [], []
            for gt_idx, i in enumerate(labelled):
                asset, obj_id = objects[i], objects[i].manifest.obj_id
                T_cam_obj = T_cam_world @ poses[i]
                window = object_depth_window(assets.raycaster(obj_id), assets.hull(obj_id), T_cam_obj, K_canvas, W, H)
                info, mask, visible = bop.gt_info_entry(window, out.depth, K, cfg.visib_delta)
                name = bop.mask_name(im_id, gt_idx)
                writer.image(scene_dir / "mask" / name, mask.astype(np.uint8) * 255)
                writer.image(scene_dir / "mask_visib" / name, visible.astype(np.uint8) * 255)
                gts.append(bop.pose_entry(T_cam_obj, obj_id))
                infos.append(info)
                coco_instances.append(CocoInstance(im_id, obj_id, mask, visible, info["visib_fract"]))
                if cfg.dope_json and info["px_count_visib"] > 0:
                    lo, hi = asset.surface.bounds
                    dope_objects.append(dope_object(asset.name, obj_id, gt_idx, T_cam_obj, poses[i], lo,
                                                    hi - lo, K, info))
            scene_gt[str(im_id)] = gts
            scene_info[str(im_id)] = infos
            if cfg.dope_json:
                write_json(scene_dir / "rgb" / f"{im_id:06d}.json", dope_image(K, T_cam_world, W, H, dope_objects))
            on_frame()
    finally:
        writer.close()
    write_json(scene_dir / "scene_gt.json", scene_gt)
    write_json(scene_dir / "scene_camera.json", scene_camera)
    write_json(scene_dir / "scene_gt_info.json", scene_info)
    for name, modal in (("scene_gt_coco.json", False), ("scene_gt_coco_modal.json", True)):
        write_json(scene_dir / name, scene_coco(sorted(assets.objects), cfg.dataset_name, coco_images,
                                                 coco_instances, modal))


def build_scene(split: Path, scene_id: int, cfg: GenerateConfig, assets: Assets,
                on_frame: Callable[[], None] = lambda: None) -> None:
    """Scene ``scene_id`` built in ``split/.SSSSSS.tmp`` and renamed to ``split/SSSSSS`` once complete."""
    final = split / f"{scene_id:06d}"
    tmp = split / f".{scene_id:06d}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)  # left over by a killed run
    try:
        render_scene(tmp, scene_id, cfg, assets, on_frame)
        tmp.rename(final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise



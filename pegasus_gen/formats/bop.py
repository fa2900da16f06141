"""BOP format (bop_toolkit's definitions), written and read: poses and cameras in mm, depth PNGs, gt_info, test
targets, BOP19 results files; the frames, models and models_info of a BOP dataset read back as arrays.
(Writing the models: ``dataset.models``; COCO: ``dataset.coco``.)

Inside the code poses, depths and models are metres; every function here converts to and from BOP's
millimetres at the files, and no other module does.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import trimesh

from pegasus_gen.errors import PegasusError
from pegasus_gen.io.files import read_json, write_atomic

IMAGE_EXTENSIONS = (".jpg", ".png", ".jpeg")


def mask_name(im_id: int, gt_index: int) -> str:
    """The file name of instance ``gt_index`` of image ``im_id`` in a scene's mask/ and mask_visib/ folders."""
    return f"{im_id:06d}_{gt_index:06d}.png"


def pose_entry(T_cam_obj: np.ndarray, obj_id: int) -> dict:
    """scene_gt entry: {"obj_id", "cam_R_m2c" (9, row-major), "cam_t_m2c" (3, mm)} of T_cam_obj [4, 4] (m)."""
    return {"obj_id": int(obj_id), "cam_R_m2c": [float(v) for v in np.asarray(T_cam_obj)[:3, :3].ravel()],
            "cam_t_m2c": [float(v) * 1000.0 for v in np.asarray(T_cam_obj)[:3, 3]]}


def camera_entry(K: np.ndarray, T_cam_world: np.ndarray, depth_scale: float) -> dict:
    """scene_camera entry: cam_K (9, row-major), depth_scale, cam_R_w2c (9), cam_t_w2c (3, mm)."""
    return {"cam_K": [float(v) for v in np.asarray(K).ravel()], "depth_scale": float(depth_scale),
            "cam_R_w2c": [float(v) for v in np.asarray(T_cam_world)[:3, :3].ravel()],
            "cam_t_w2c": [float(v) * 1000.0 for v in np.asarray(T_cam_world)[:3, 3]]}


def read_depth_png(path: str | os.PathLike, depth_scale: float) -> np.ndarray:
    """The depth image [H, W] float64 in metres (0 where there is none) of a BOP depth PNG whose values times
    ``depth_scale`` are mm; a PegasusError when it is not a single-channel image."""
    values = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if values is None or values.ndim != 2:
        raise PegasusError(f"{path}: not a single-channel depth image")
    return values.astype(np.float64) * depth_scale / 1000.0


def depth_to_png_values(depth_m: np.ndarray, depth_scale: float) -> np.ndarray:
    """[H, W] z-depth in metres -> uint16 such that value * depth_scale = mm (clipped to 65535)."""
    return np.clip(np.round(depth_m * 1000.0 / depth_scale), 0, 65535).astype(np.uint16)


def _bbox(mask: np.ndarray, dx: int = 0, dy: int = 0) -> list[int]:
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    x0, y0 = int(xs.min()), int(ys.min())
    return [x0 - dx, y0 - dy, int(xs.max()) - x0 + 1, int(ys.max()) - y0 + 1]


@functools.lru_cache(maxsize=8)
def _ray_lengths(K_entries: tuple, width: int, height: int) -> np.ndarray:
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    x = (u - K_entries[2]) / K_entries[0]
    y = (v - K_entries[5]) / K_entries[4]
    lengths = np.sqrt(x * x + y * y + 1.0)
    lengths.flags.writeable = False
    return lengths


def ray_lengths(K: np.ndarray, width: int, height: int) -> np.ndarray:
    """[H, W] factor turning z-depth into distance along each pixel's ray: ||K^-1 [u, v, 1]|| (read-only, computed
    once per camera)."""
    return _ray_lengths(tuple(float(v) for v in np.asarray(K).ravel()), int(width), int(height))


@dataclass
class CanvasWindow:
    """An object's z-depth on calc_gt_info's canvas (three times the image, principal point shifted by (W, H)),
    held as the window around the object: depth [h, w] (m, 0 where the object is absent) at canvas pixels
    x0.., y0..; the canvas is 0 outside it."""

    depth: np.ndarray
    x0: int = 0
    y0: int = 0

    def canvas(self, width: int, height: int) -> np.ndarray:
        """The whole [3H, 3W] canvas of an image of ``width`` x ``height`` px."""
        canvas = np.zeros((3 * height, 3 * width), self.depth.dtype)
        h, w = self.depth.shape
        canvas[self.y0:self.y0 + h, self.x0:self.x0 + w] = self.depth
        return canvas


def gt_info_entry(window: CanvasWindow, scene_depth: np.ndarray, K: np.ndarray,
                  delta: float = 0.015) -> tuple[dict, np.ndarray, np.ndarray]:
    """(scene_gt_info entry, full mask [H, W], visible mask [H, W]) as bop_toolkit's calc_gt_info.

    window: the object rendered alone on the 3x canvas (:class:`CanvasWindow`); scene_depth [H, W] (m).
    A pixel is visible where the object is and its distance along the ray exceeds the scene's by at
    most ``delta`` (m), or the scene has no depth there.
    """
    height, width = scene_depth.shape
    present = window.depth > 0
    px_all = int(present.sum())
    mask = np.zeros((height, width), bool)
    visible = np.zeros((height, width), bool)
    valid = 0
    h, w = window.depth.shape
    # the image's part of the window, in image pixels [iy0:iy1, ix0:ix1]
    ix0, iy0 = max(window.x0 - width, 0), max(window.y0 - height, 0)
    ix1, iy1 = min(window.x0 + w - width, width), min(window.y0 + h - height, height)
    if ix0 < ix1 and iy0 < iy1:
        object_depth = window.depth[iy0 + height - window.y0:iy1 + height - window.y0,
                                    ix0 + width - window.x0:ix1 + width - window.x0]
        scene = scene_depth[iy0:iy1, ix0:ix1]
        rays = ray_lengths(K, width, height)[iy0:iy1, ix0:ix1]
        inside = object_depth > 0
        mask[iy0:iy1, ix0:ix1] = inside
        visible[iy0:iy1, ix0:ix1] = inside & ((object_depth * rays - scene * rays <= delta) | (scene == 0))
        valid = int((inside & (scene > 0)).sum())
    px_visib = int(visible.sum())
    info = {"bbox_obj": _bbox(present, width - window.x0, height - window.y0), "bbox_visib": _bbox(visible),
            "px_count_all": px_all, "px_count_valid": valid,
            "px_count_visib": px_visib, "visib_fract": px_visib / px_all if px_all else 0.0}
    return info, mask, visible


def targets_bop19(split_dir: Path, min_visib_fract: float = 0.1) -> list[dict]:
    """BOP19 test targets of a split, as bop_toolkit's enumerate_test_targets.py makes them: per scene, image
    and object, {"scene_id", "im_id", "obj_id", "inst_count"} counting the instances at visib_fract >=
    ``min_visib_fract``; objects with no such instance are not targets."""
    targets = []
    for scene in sorted(p for p in Path(split_dir).iterdir() if p.is_dir() and not p.name.startswith(".")):
        gt, infos = read_json(scene / "scene_gt.json"), read_json(scene / "scene_gt_info.json")
        for im_id in sorted(gt, key=int):
            counts: dict[int, int] = {}
            for entry, info in zip(gt[im_id], infos[im_id]):
                if info["visib_fract"] >= min_visib_fract:
                    counts[int(entry["obj_id"])] = counts.get(int(entry["obj_id"]), 0) + 1
            targets += [{"scene_id": int(scene.name), "im_id": int(im_id), "obj_id": obj_id, "inst_count": n}
                        for obj_id, n in counts.items()]
    return targets


def read_targets_bop19(root: Path, split: str) -> dict[tuple[int, int, int], int] | None:
    """A BOP dataset's targets for ``split`` (``ROOT/{split}_targets_bop19.json``, :func:`targets_bop19`'s form)
    as {(scene_id, im_id, obj_id): inst_count}; None when the dataset has no such file. A malformed file is a
    PegasusError."""
    path = Path(root) / f"{split}_targets_bop19.json"
    if not path.is_file():
        return None
    try:
        return {(int(t["scene_id"]), int(t["im_id"]), int(t["obj_id"])): int(t["inst_count"]) for t in read_json(path)}
    except (TypeError, KeyError, ValueError) as exc:
        raise PegasusError(f"{path}: not a list of scene_id, im_id, obj_id, inst_count entries "
                           f"({type(exc).__name__}: {exc})") from None


BOP19_HEADER = "scene_id,im_id,obj_id,score,R,t,time"


def result_row(scene_id: int, im_id: int, obj_id: int, score: float, T_cam_obj: np.ndarray, seconds: float) -> dict:
    """One estimate (T_cam_obj [4, 4], m) as a row of :func:`write_bop_results` (t in mm)."""
    return {"scene_id": int(scene_id), "im_id": int(im_id), "obj_id": int(obj_id), "score": float(score),
            "R": np.asarray(T_cam_obj)[:3, :3].ravel().tolist(), "t": (np.asarray(T_cam_obj)[:3, 3] * 1000.0).tolist(),
            "time": seconds}


def write_bop_results(path: str | os.PathLike, rows: list[dict]) -> Path:
    """A BOP19 results file (bop_toolkit's ``save_bop_results``): one line per estimate, R as 9 numbers
    row-major and t as 3 numbers in mm, space-separated; time in seconds (-1: unknown), the same for every
    estimate of an image. rows: dicts with scene_id, im_id, obj_id, score, R [9], t [3] (mm), time."""
    lines = [BOP19_HEADER] + [
        f"{r['scene_id']},{r['im_id']},{r['obj_id']},{r['score']},{' '.join(str(float(v)) for v in r['R'])},"
        f"{' '.join(str(float(v)) for v in r['t'])},{r.get('time', -1)}" for r in rows]
    return write_atomic(path, lambda f: f.write(("\n".join(lines) + "\n").encode()))


def read_bop_results(path: str | os.PathLike) -> list[dict]:
    """The rows of a BOP19 results file: scene_id, im_id, obj_id (int), score, time (float), R [3, 3], t [3]
    (mm) as arrays."""
    lines = Path(path).read_text().splitlines()
    if not lines or lines[0].strip() != BOP19_HEADER:
        raise PegasusError(f"{path}: not a BOP19 results file (header {BOP19_HEADER!r} expected)")
    rows = []
    for n, line in enumerate(lines[1:], 2):
        fields = line.split(",")
        if len(fields) != 7:
            raise PegasusError(f"{path}:{n}: 7 comma-separated fields expected, got {len(fields)}")
        R, t = np.array(fields[4].split(), float), np.array(fields[5].split(), float)
        if R.shape != (9,) or t.shape != (3,):
            raise PegasusError(f"{path}:{n}: R needs 9 numbers and t 3")
        rows.append({"scene_id": int(fields[0]), "im_id": int(fields[1]), "obj_id": int(fields[2]),
                     "score": float(fields[3]), "R": R.reshape(3, 3), "t": t, "time": float(fields[6])})
    return rows


# ------------------------------------------------------------------ reading
def model_boxes(root: Path) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """{obj_id: (bbox_min [3], bbox_size [3]) in metres} from a BOP dataset's models/models_info.json."""
    return {k: (info.bbox_min, info.bbox_size) for k, info in models_info(root).items()}


@dataclass(frozen=True)
class ModelInfo:
    """One object's models_info.json entry in metres: bbox_min [3], bbox_size [3], diameter (None where the
    entry has none); whether it lists discrete or continuous symmetries."""

    bbox_min: np.ndarray
    bbox_size: np.ndarray
    diameter: float | None
    symmetric: bool


def models_info(root: Path) -> dict[int, ModelInfo]:
    """{obj_id: ModelInfo} of a BOP dataset's models/models_info.json; a PegasusError naming the file and the
    object when an entry lacks a field."""
    path = Path(root) / "models" / "models_info.json"
    out = {}
    for key, v in read_json(path).items():
        try:
            out[int(key)] = ModelInfo(np.array([v["min_x"], v["min_y"], v["min_z"]], float) / 1000.0,
                                      np.array([v["size_x"], v["size_y"], v["size_z"]], float) / 1000.0,
                                      float(v["diameter"]) / 1000.0 if "diameter" in v else None,
                                      bool(v.get("symmetries_discrete") or v.get("symmetries_continuous")))
        except (KeyError, TypeError, ValueError) as exc:
            raise PegasusError(f"{path}: obj_id {key}: not a BOP models_info entry ({type(exc).__name__}: {exc})") \
                from None
    return out


def read_model(root: Path, obj_id: int, evaluation: bool = False) -> trimesh.Trimesh:
    """The BOP model of ``obj_id`` (models/obj_XXXXXX.ply, mm) as a mesh in metres; with ``evaluation`` the
    one in models_eval/ when the dataset has it. A PegasusError when it is missing or unreadable."""
    folders = ("models_eval", "models") if evaluation else ("models",)
    path = next((p for p in (Path(root) / f / f"obj_{obj_id:06d}.ply" for f in folders) if p.is_file()),
                Path(root) / "models" / f"obj_{obj_id:06d}.ply")
    if not path.is_file():
        raise PegasusError(f"{path}: the model of obj_id {obj_id} is missing")
    try:
        mesh = trimesh.load(path, process=False, force="mesh")
    except (OSError, ValueError) as exc:
        raise PegasusError(f"{path}: cannot read the model of obj_id {obj_id} ({exc})") from None
    mesh.apply_scale(0.001)
    return mesh


def object_names(root: Path) -> dict[str, int]:
    """{name: obj_id} from the ``name`` fields pegasus writes into models/models_info.json (empty for a
    dataset without them)."""
    info = read_json(Path(root) / "models" / "models_info.json")
    return {v["name"]: int(k) for k, v in info.items() if "name" in v}


@dataclass
class BopInstance:
    """One ground-truth instance: obj_id, T_cam_obj [4, 4] (m), its index in scene_gt and visib_fract (None
    without scene_gt_info.json)."""

    obj_id: int
    T: np.ndarray
    index: int
    visib_fract: float | None


@dataclass
class BopFrame:
    """One image of a BOP split: scene folder, im_id, image path, K [3, 3], the instances in it, and its
    depth image (None without one) with the depth_scale (png value * depth_scale = mm)."""

    scene: Path
    im_id: int
    image: Path
    K: np.ndarray
    instances: list[BopInstance]
    depth: Path | None = None
    depth_scale: float = 1.0

    def visible_masks(self) -> list[Path]:
        """The visible masks (``mask_visib``) of its instances that are on disk, in instance order."""
        masks = (self.scene / "mask_visib" / mask_name(self.im_id, inst.index) for inst in self.instances)
        return [m for m in masks if m.is_file()]

    def read_depth(self) -> np.ndarray:
        """The depth image [H, W] in metres (0 where there is none)."""
        if self.depth is None:
            raise PegasusError(f"{self.scene}: no depth image for im_id {self.im_id}")
        return read_depth_png(self.depth, self.depth_scale)


def bop_frames(split_dir: str | Path, max_per_scene: int | None = None):
    """Iterate over the BopFrames of a BOP split folder, scene by scene, in im_id order (the first
    ``max_per_scene`` of each scene when given). A scene whose JSON files do not follow the BOP format is a
    PegasusError naming the file and what is wrong."""
    split_dir = Path(split_dir)
    if not split_dir.is_dir():
        raise PegasusError(f"{split_dir.parent}: no {split_dir.name}/ folder, so not a BOP dataset")
    for scene in sorted(p for p in split_dir.iterdir() if p.is_dir() and not p.name.startswith(".")):
        yield from _scene_frames(scene, max_per_scene)


def _scene_frames(scene: Path, max_per_scene: int | None) -> list[BopFrame]:
    gt = read_json(scene / "scene_gt.json")
    cams = read_json(scene / "scene_camera.json")
    infos = read_json(scene / "scene_gt_info.json") if (scene / "scene_gt_info.json").is_file() else {}
    for name, table in (("scene_gt.json", gt), ("scene_camera.json", cams), ("scene_gt_info.json", infos)):
        if not isinstance(table, dict) or not all(isinstance(k, str) and k.isdigit() for k in table):
            raise PegasusError(f"{scene / name}: not a BOP file (an object keyed by image ids)")
    frames = []
    for im_id in sorted(gt, key=int)[:max_per_scene]:
        where = f"{scene}: image {im_id}"
        try:
            instances = []
            for n, entry in enumerate(gt[im_id]):
                obj_id = entry["obj_id"]
                if not isinstance(obj_id, int) or isinstance(obj_id, bool):
                    raise ValueError(f"obj_id {obj_id!r} is not an integer")
                T = np.eye(4)
                T[:3, :3] = np.array(entry["cam_R_m2c"], dtype=np.float64).reshape(3, 3)
                T[:3, 3] = np.array(entry["cam_t_m2c"], dtype=np.float64) / 1000.0
                visib = float(infos[im_id][n]["visib_fract"]) if im_id in infos else None
                instances.append(BopInstance(obj_id, T, n, visib))
            K = np.array(cams[im_id]["cam_K"], dtype=np.float64).reshape(3, 3)
            depth_scale = float(cams[im_id].get("depth_scale", 1.0))
        except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
            raise PegasusError(f"{where}: scene_gt/scene_camera do not follow the BOP format "
                               f"({type(exc).__name__}: {exc})") from None
        image = next((scene / "rgb" / f"{int(im_id):06d}{e}" for e in IMAGE_EXTENSIONS
                      if (scene / "rgb" / f"{int(im_id):06d}{e}").is_file()), None)
        if image is None:
            raise PegasusError(f"{scene}/rgb: no image {int(im_id):06d}")
        depth = scene / "depth" / f"{int(im_id):06d}.png"
        frames.append(BopFrame(scene, int(im_id), image, K, instances, depth if depth.is_file() else None,
                               depth_scale))
    return frames

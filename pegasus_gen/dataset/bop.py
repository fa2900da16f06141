"""BOP format (bop_toolkit's definitions), written and read: poses and cameras in mm, model PLYs, models_info,
gt_info; and the frames of a BOP split read back as arrays.

Inside the code poses are metres; every function here converts to and from BOP's millimetres at the files.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import trimesh

from pegasus_gen.errors import PegasusError
from pegasus_gen.io.files import read_json, write_atomic

IMAGE_EXTENSIONS = (".jpg", ".png", ".jpeg")


def pose_entry(T_cam_obj: np.ndarray, obj_id: int) -> dict:
    """scene_gt entry: {"obj_id", "cam_R_m2c" (9, row-major), "cam_t_m2c" (3, mm)} of T_cam_obj [4, 4] (m)."""
    return {"obj_id": int(obj_id), "cam_R_m2c": [float(v) for v in np.asarray(T_cam_obj)[:3, :3].ravel()],
            "cam_t_m2c": [float(v) * 1000.0 for v in np.asarray(T_cam_obj)[:3, 3]]}


def camera_entry(K: np.ndarray, T_cam_world: np.ndarray, depth_scale: float) -> dict:
    """scene_camera entry: cam_K (9, row-major), depth_scale, cam_R_w2c (9), cam_t_w2c (3, mm)."""
    return {"cam_K": [float(v) for v in np.asarray(K).ravel()], "depth_scale": float(depth_scale),
            "cam_R_w2c": [float(v) for v in np.asarray(T_cam_world)[:3, :3].ravel()],
            "cam_t_w2c": [float(v) * 1000.0 for v in np.asarray(T_cam_world)[:3, 3]]}


def depth_to_png_values(depth_m: np.ndarray, depth_scale: float) -> np.ndarray:
    """[H, W] z-depth in metres -> uint16 such that value * depth_scale = mm (clipped to 65535)."""
    return np.clip(np.round(depth_m * 1000.0 / depth_scale), 0, 65535).astype(np.uint16)


def write_model_ply(path: str | os.PathLike, mesh: trimesh.Trimesh) -> Path:
    """Binary PLY of ``mesh`` in millimetres: vertices (float x y z nx ny nz), faces ``vertex_indices``."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64) * 1000.0
    normals = np.asarray(mesh.vertex_normals, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    header = "\n".join([
        "ply", "format binary_little_endian 1.0", f"element vertex {len(vertices)}",
        "property float x", "property float y", "property float z",
        "property float nx", "property float ny", "property float nz",
        f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]) + "\n"
    vertex_table = np.concatenate([vertices, normals], axis=1).astype("<f4")
    face_table = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face_table["n"] = 3
    face_table["v"] = faces

    def write(f):
        f.write(header.encode("ascii"))
        f.write(vertex_table.tobytes())
        f.write(face_table.tobytes())

    return write_atomic(path, write)


def models_info_entry(mesh: trimesh.Trimesh, symmetries_discrete=(), symmetries_continuous=()) -> dict:
    """models_info entry in mm: diameter (largest vertex distance), min_x.., size_x.., symmetries.

    symmetries_discrete: 4x4 transforms (16 numbers, translation in m); symmetries_continuous:
    objects with ``axis`` and ``offset`` (m).
    """
    v = np.asarray(mesh.vertices, dtype=np.float64) * 1000.0
    hull = np.asarray(trimesh.convex.convex_hull(v).vertices) if len(v) > 3 else v  # the diameter lies on the hull
    diameter = float(np.max(np.linalg.norm(hull[:, None, :] - hull[None, :, :], axis=-1)))
    lo, hi = v.min(0), v.max(0)
    info = {"diameter": diameter, "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
            "size_x": float(hi[0] - lo[0]), "size_y": float(hi[1] - lo[1]), "size_z": float(hi[2] - lo[2])}
    if len(symmetries_discrete):
        mats = []
        for sym in symmetries_discrete:
            m = np.asarray(sym, dtype=np.float64).reshape(4, 4).copy()
            m[:3, 3] *= 1000.0
            mats.append([float(x) for x in m.ravel()])
        info["symmetries_discrete"] = mats
    if len(symmetries_continuous):
        info["symmetries_continuous"] = [
            {"axis": [float(a) for a in s.axis], "offset": [float(o) * 1000.0 for o in s.offset]}
            for s in symmetries_continuous]
    return info


def _bbox(mask: np.ndarray, dx: int = 0, dy: int = 0) -> list[int]:
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    x0, y0 = int(xs.min()), int(ys.min())
    return [x0 - dx, y0 - dy, int(xs.max()) - x0 + 1, int(ys.max()) - y0 + 1]


def ray_lengths(K: np.ndarray, width: int, height: int) -> np.ndarray:
    """[H, W] factor turning z-depth into distance along each pixel's ray: ||K^-1 [u, v, 1]||."""
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    x = (u - K[0, 2]) / K[0, 0]
    y = (v - K[1, 2]) / K[1, 1]
    return np.sqrt(x * x + y * y + 1.0)


def gt_info_entry(object_depth_canvas: np.ndarray, scene_depth: np.ndarray, K: np.ndarray,
                  delta: float = 0.015) -> tuple[dict, np.ndarray, np.ndarray]:
    """(scene_gt_info entry, full mask [H, W], visible mask [H, W]) as bop_toolkit's calc_gt_info.

    object_depth_canvas [3H, 3W]: z-depth (m) of the object rendered alone on a canvas three times the
    image with the principal point shifted by (W, H), 0 where it is absent; scene_depth [H, W] (m).
    A pixel is visible where the object is and its distance along the ray exceeds the scene's by at
    most ``delta`` (m), or the scene has no depth there.
    """
    height, width = scene_depth.shape
    full_canvas = object_depth_canvas > 0
    object_depth = object_depth_canvas[height:2 * height, width:2 * width]
    mask = object_depth > 0
    rays = ray_lengths(K, width, height)
    visible = mask & ((object_depth * rays - scene_depth * rays <= delta) | (scene_depth == 0))
    px_all = int(full_canvas.sum())
    px_visib = int(visible.sum())
    info = {"bbox_obj": _bbox(full_canvas, width, height), "bbox_visib": _bbox(visible),
            "px_count_all": px_all, "px_count_valid": int((mask & (scene_depth > 0)).sum()),
            "px_count_visib": px_visib, "visib_fract": px_visib / px_all if px_all else 0.0}
    return info, mask, visible


def coco_rle(mask: np.ndarray) -> dict:
    """Uncompressed COCO run-length encoding of a binary mask [H, W]: run lengths over the column-major
    pixel order, starting with a (possibly empty) run of zeros; {"counts": [...], "size": [H, W]}."""
    flat = np.asarray(mask, dtype=bool).ravel(order="F")
    changes = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    bounds = np.concatenate([[0], changes, [flat.size]])
    counts = np.diff(bounds).tolist()
    if flat.size and flat[0]:
        counts = [0] + counts
    return {"counts": [int(c) for c in counts], "size": [int(mask.shape[0]), int(mask.shape[1])]}


def coco_annotation(ann_id: int, im_id: int, obj_id: int, mask_visib: np.ndarray, gt_info: dict,
                    min_visib_fract: float = 0.1) -> dict:
    """scene_gt_coco annotation of one instance as bop_toolkit's calc_gt_coco: its visible mask as RLE,
    bbox = bbox_visib (x, y, w, h), area = visible pixels, ``ignore`` below ``min_visib_fract``."""
    h, w = mask_visib.shape
    return {"id": int(ann_id), "image_id": int(im_id), "category_id": int(obj_id), "iscrowd": 0,
            "area": int(np.count_nonzero(mask_visib)), "bbox": list(gt_info["bbox_visib"]),
            "segmentation": coco_rle(mask_visib), "width": int(w), "height": int(h),
            "ignore": bool(gt_info["visib_fract"] < min_visib_fract)}


def coco_dataset(categories: dict[int, str], images: list[dict], annotations: list[dict]) -> dict:
    """scene_gt_coco.json content: categories {obj_id: name}, images [{id, file_name, width, height}]."""
    return {"info": {"description": "pegasus generate", "version": "1.0"}, "licenses": [],
            "categories": [{"id": int(k), "name": v, "supercategory": "pegasus"}
                           for k, v in sorted(categories.items())],
            "images": images, "annotations": annotations}


# ------------------------------------------------------------------ reading
def model_boxes(root: Path) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """{obj_id: (bbox_min [3], bbox_size [3]) in metres} from a BOP dataset's models/models_info.json."""
    info = read_json(Path(root) / "models" / "models_info.json")
    return {int(k): (np.array([v["min_x"], v["min_y"], v["min_z"]]) / 1000.0,
                     np.array([v["size_x"], v["size_y"], v["size_z"]]) / 1000.0) for k, v in info.items()}


def object_names(split_dir: Path) -> dict[str, int]:
    """{name: obj_id} from the scenes' scene_gt_coco.json categories (empty when there are none)."""
    names = {}
    for coco in sorted(split_dir.glob("*/scene_gt_coco.json")):
        for category in read_json(coco).get("categories", []):
            names[category["name"]] = int(category["id"])
    return names


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

    def read_depth(self) -> np.ndarray:
        """The depth image [H, W] in metres (0 where there is none)."""
        if self.depth is None:
            raise PegasusError(f"{self.scene}: no depth image for im_id {self.im_id}")
        values = cv2.imread(str(self.depth), cv2.IMREAD_UNCHANGED)
        if values is None or values.ndim != 2:
            raise PegasusError(f"{self.depth}: not a single-channel depth image")
        return values.astype(np.float64) * self.depth_scale / 1000.0


def bop_frames(split_dir: str | Path, max_per_scene: int | None = None):
    """Iterate over the BopFrames of a BOP split folder, scene by scene, in im_id order (the first
    ``max_per_scene`` of each scene when given)."""
    split_dir = Path(split_dir)
    for scene in sorted(p for p in split_dir.iterdir() if p.is_dir() and not p.name.startswith(".")):
        gt = read_json(scene / "scene_gt.json")
        cams = read_json(scene / "scene_camera.json")
        infos = read_json(scene / "scene_gt_info.json") if (scene / "scene_gt_info.json").is_file() else {}
        for im_id in sorted(gt, key=int)[:max_per_scene]:
            image = next((scene / "rgb" / f"{int(im_id):06d}{e}" for e in IMAGE_EXTENSIONS
                          if (scene / "rgb" / f"{int(im_id):06d}{e}").is_file()), None)
            if image is None:
                raise PegasusError(f"{scene}/rgb: no image {int(im_id):06d}")
            instances = []
            for n, entry in enumerate(gt[im_id]):
                T = np.eye(4)
                T[:3, :3] = np.array(entry["cam_R_m2c"], dtype=np.float64).reshape(3, 3)
                T[:3, 3] = np.array(entry["cam_t_m2c"], dtype=np.float64) / 1000.0
                visib = infos[im_id][n]["visib_fract"] if im_id in infos else None
                instances.append(BopInstance(int(entry["obj_id"]), T, n, visib))
            depth = scene / "depth" / f"{int(im_id):06d}.png"
            yield BopFrame(scene, int(im_id), image, np.array(cams[im_id]["cam_K"], dtype=np.float64).reshape(3, 3),
                           instances, depth if depth.is_file() else None, float(cams[im_id].get("depth_scale", 1.0)))

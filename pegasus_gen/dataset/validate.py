"""`pegasus validate`: check a BOP dataset against its own models, independently of the writer.

What is checked, per the BOP format (bop_toolkit docs): camera.json, models_info.json and model PLYs are
there and in millimetres; every scene's scene_gt / scene_camera / scene_gt_info hold the same images,
with well-formed entries (rotation matrices orthonormal, objects in front of the camera, known obj_ids);
images, depth and masks exist with the right size; mask_visib lies within mask and gt_info's counts and
boxes match the masks. Then geometry, with the models ray cast at their GT poses (no splats involved):
each model's silhouette covers its mask (IoU >= ``min_iou`` where the mask is large enough, counted
outside a ``boundary_px`` band around the model's outline: splats reach ~1 mm past the surface their
mesh was made from, so a 1-px rim is expected and says nothing about the pose) and the depth image at
visible pixels agrees with the posed model: median absolute difference <= ``max_depth_mm``, or
``depth_px`` pixel footprints (the object's median depth / fx) when that is more. A rendered pixel's depth
blends the surface over the pixel's area, front-most first, so on a slanted surface it lies up to about a
footprint in front: at 160x120 and 1 m that is 7 mm, at 320x240 half of it.

A dataset made by pegasus generate records the scenes it holds when complete (``pegasus_config.yaml``); one
that holds fewer (a run that was killed or failed) is reported, however good its scenes are.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import trimesh
from tqdm import tqdm

from pegasus_gen.dataset.config import CONFIG_FILE
from pegasus_gen.errors import PegasusError
from pegasus_gen.formats.bop import mask_name
from pegasus_gen.io.files import parse_yaml, read_json
from pegasus_gen.render.raycast import MeshRaycaster

GT_INFO_KEYS = ("bbox_obj", "bbox_visib", "px_count_all", "px_count_valid", "px_count_visib", "visib_fract")


@dataclass
class Report:
    """Problems found (one line each) and what was measured on the checked instances."""

    problems: list[str] = field(default_factory=list)
    images: int = 0
    instances: int = 0
    ious: list[float] = field(default_factory=list)  # instances with masks >= min_mask_px, outside the band
    depth_errors_mm: list[float] = field(default_factory=list)  # median |depth - model| per visible instance

    @property
    def ok(self) -> bool:
        return not self.problems

    def summary(self) -> str:
        lines = [f"{self.images} images, {self.instances} instances checked"]
        if self.ious:
            lines.append(f"mask vs model IoU (outside the outline band): min {min(self.ious):.3f}, "
                         f"median {np.median(self.ious):.3f} "
                         f"({len(self.ious)} instances)")
        if self.depth_errors_mm:
            lines.append(f"depth vs model (median |diff| per instance): max {max(self.depth_errors_mm):.2f} mm, "
                         f"median {np.median(self.depth_errors_mm):.2f} mm ({len(self.depth_errors_mm)} instances)")
        lines.append("OK" if self.ok else f"{len(self.problems)} problem(s)")
        return "\n".join(lines)


def _matrix(values, rows: int, cols: int, what: str) -> np.ndarray:
    a = np.asarray(values, dtype=np.float64)
    if a.size != rows * cols:
        raise ValueError(f"{what} has {a.size} numbers, expected {rows * cols}")
    return a.reshape(rows, cols)


def _bbox(mask: np.ndarray) -> list[int]:
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)]


def _read_mask(path: Path, shape) -> np.ndarray:
    mask = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if mask is None:
        raise ValueError(f"{path.name} missing or unreadable")
    if mask.shape[:2] != shape:
        raise ValueError(f"{path.name} is {mask.shape[1]}x{mask.shape[0]}, the image {shape[1]}x{shape[0]}")
    return mask > 0


def _load_models(root: Path, report: Report) -> dict[int, MeshRaycaster]:
    info = read_json(root / "models" / "models_info.json")
    models = {}
    for key, entry in info.items():
        where = f"models_info.json[{key}]"
        missing = [k for k in ("diameter", "min_x", "min_y", "min_z", "size_x", "size_y", "size_z") if k not in entry]
        if missing:
            report.problems.append(f"{where}: missing {', '.join(missing)}")
            continue
        if not 1.0 <= entry["diameter"] <= 10_000.0:
            report.problems.append(f"{where}: diameter {entry['diameter']} is not in mm (1..10000 expected)")
        path = root / "models" / f"obj_{int(key):06d}.ply"
        try:
            mesh = trimesh.load(path, force="mesh", process=False)
        except Exception as exc:  # trimesh raises many kinds for unreadable files
            report.problems.append(f"{path}: cannot read the model ({exc})")
            continue
        size = np.ptp(mesh.vertices, axis=0)
        if not np.allclose(size, [entry["size_x"], entry["size_y"], entry["size_z"]], atol=0.5):
            report.problems.append(f"{where}: size {np.round(size, 1).tolist()} mm of the PLY differs from the entry")
        models[int(key)] = MeshRaycaster(mesh)
    return models


def _image_file(scene: Path, im_id: int) -> Path | None:
    for ext in ("jpg", "png", "jpeg"):
        path = scene / "rgb" / f"{im_id:06d}.{ext}"
        if path.is_file():
            return path
    return None


def _iou_outside_band(silhouette: np.ndarray, mask: np.ndarray, boundary_px: int) -> float:
    """IoU of two [H, W] masks over the pixels farther than ``boundary_px`` from the silhouette's outline."""
    kernel = np.ones((2 * boundary_px + 1, 2 * boundary_px + 1), np.uint8)
    s = silhouette.astype(np.uint8)
    band = (cv2.dilate(s, kernel) > 0) & ~(cv2.erode(s, kernel) > 0)
    union = ((silhouette | mask) & ~band).sum()
    return float(((silhouette & mask) & ~band).sum() / union) if union else 1.0


def _check_image(scene: Path, im_id: int, gts, camera, infos, models, report: Report, *, min_mask_px: int,
                 min_iou: float, boundary_px: int, max_depth_mm: float, depth_px: float,
                 min_visible_px: int) -> None:
    where = f"{scene.name}/{im_id:06d}"
    K = _matrix(camera["cam_K"], 3, 3, "cam_K")
    if not camera.get("depth_scale", 0) > 0:
        raise ValueError("scene_camera depth_scale must be > 0")
    rgb_path = _image_file(scene, im_id)
    if rgb_path is None:
        raise ValueError("rgb image missing")
    rgb = cv2.imread(str(rgb_path), cv2.IMREAD_UNCHANGED)
    depth = cv2.imread(str(scene / "depth" / f"{im_id:06d}.png"), cv2.IMREAD_UNCHANGED)
    if depth is None or depth.dtype != np.uint16:
        raise ValueError("depth image missing or not 16-bit")
    if rgb is None or rgb.shape[:2] != depth.shape:
        raise ValueError("rgb missing, unreadable or not the size of the depth image")
    height, width = depth.shape
    depth_mm = depth.astype(np.float64) * camera["depth_scale"]
    if len(infos) != len(gts):
        raise ValueError(f"{len(gts)} scene_gt entries but {len(infos)} scene_gt_info entries")
    report.images += 1
    for gt_idx, (gt, info) in enumerate(zip(gts, infos)):
        name = f"{where}_{gt_idx:06d}"
        R = _matrix(gt["cam_R_m2c"], 3, 3, "cam_R_m2c")
        t = _matrix(gt["cam_t_m2c"], 3, 1, "cam_t_m2c").ravel()
        if not (np.allclose(R @ R.T, np.eye(3), atol=1e-5) and np.linalg.det(R) > 0):
            report.problems.append(f"{name}: cam_R_m2c is not a rotation")
            continue
        if not 10.0 < t[2] < 100_000.0:
            report.problems.append(f"{name}: cam_t_m2c z = {t[2]:.4g} is not a depth in mm in front of the camera")
            continue
        if gt["obj_id"] not in models:
            report.problems.append(f"{name}: obj_id {gt['obj_id']} has no model")
            continue
        if any(k not in info for k in GT_INFO_KEYS):
            report.problems.append(f"{name}: scene_gt_info entry lacks one of {', '.join(GT_INFO_KEYS)}")
            continue
        mask = _read_mask(scene / "mask" / mask_name(im_id, gt_idx), depth.shape)
        visib = _read_mask(scene / "mask_visib" / mask_name(im_id, gt_idx), depth.shape)
        report.instances += 1
        if (visib & ~mask).any():
            report.problems.append(f"{name}: mask_visib reaches outside mask")
        px_visib = int(visib.sum())
        if info["px_count_visib"] != px_visib or info["bbox_visib"] != _bbox(visib):
            report.problems.append(f"{name}: px_count_visib/bbox_visib do not match mask_visib")
        if info["px_count_all"] < mask.sum() or not 0.0 <= info["visib_fract"] <= 1.0 or (
                info["px_count_all"] and abs(info["visib_fract"] - px_visib / info["px_count_all"]) > 1e-6):
            report.problems.append(f"{name}: px_count_all/visib_fract inconsistent with the masks")
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, t
        model_depth = models[gt["obj_id"]].depth(K, T, width, height)
        silhouette = model_depth > 0
        if mask.sum() >= min_mask_px:
            iou = _iou_outside_band(silhouette, mask, boundary_px)
            report.ious.append(iou)
            if iou < min_iou:
                report.problems.append(f"{name}: the posed model covers its mask with IoU {iou:.3f} < {min_iou}")
        both = visib & silhouette & (depth_mm > 0)
        if both.sum() >= min_visible_px:
            error = float(np.median(np.abs(depth_mm[both] - model_depth[both])))
            report.depth_errors_mm.append(error)
            tolerance = max(max_depth_mm, depth_px * float(np.median(model_depth[both])) / K[0, 0])
            if error > tolerance:
                report.problems.append(f"{name}: depth differs from the posed model by {error:.1f} mm (median; "
                                       f"tolerance {tolerance:.1f} mm here)")


def coco_instance_count(infos: dict) -> int:
    """The number of annotations BOP's COCO files hold for a scene_gt_info {im_id: [entry]}: instances with
    at least one visible pixel (bop_toolkit leaves the others out)."""
    return sum(1 for entries in infos.values() for entry in entries if entry.get("px_count_visib", 0) > 0)


def _check_scene_count(root: Path, split: str, present: set[str], report: Report) -> None:
    """Report the scenes ``CONFIG_FILE`` (when there: BOP datasets from elsewhere have none) says ``split`` holds
    and ``present`` (the scene folder names) lacks."""
    record = root / CONFIG_FILE
    if not record.is_file():
        return
    try:
        stored = parse_yaml(record.read_text(errors="replace"), CONFIG_FILE)
    except PegasusError as exc:
        report.problems.append(f"{exc}: the number of scenes the dataset should hold is unknown")
        return
    if not isinstance(stored, dict) or type(stored.get("scenes")) is not int:
        report.problems.append(f"{CONFIG_FILE}: no scenes count, so the number of scenes the dataset should hold "
                               "is unknown")
        return
    if stored.get("split") != split:
        return
    missing = [f"{s:06d}" for s in range(stored["scenes"]) if f"{s:06d}" not in present]
    if missing:
        shown = ", ".join(missing[:5]) + (", ..." if len(missing) > 5 else "")
        report.problems.append(f"{split}: {len(missing)} of the {stored['scenes']} scenes in {CONFIG_FILE} are "
                               f"missing ({shown}); finish the dataset with pegasus generate --resume")


def validate(root: str | Path, split: str = "train_pbr", *, min_mask_px: int = 500, min_iou: float = 0.9,
             boundary_px: int = 1, max_depth_mm: float = 5.0, depth_px: float = 2.0, min_visible_px: int = 100,
             max_images: int | None = None) -> Report:
    """Check the BOP dataset at ``root`` (see the module docstring); ``max_images`` (>= 1) per scene limits the
    work."""
    root = Path(root)
    if max_images is not None and max_images < 1:
        raise PegasusError(f"--max-images {max_images}: check at least 1 image per scene")
    if not (root / split).is_dir():
        raise PegasusError(f"{root}: no {split}/ folder, so not a BOP dataset (or choose --split)")
    report = Report()
    camera = read_json(root / "camera.json")
    missing = [k for k in ("fx", "fy", "cx", "cy", "width", "height") if k not in camera]
    if missing:
        report.problems.append(f"camera.json: missing {', '.join(missing)}")
    models = _load_models(root, report)
    scenes = sorted(p for p in (root / split).iterdir() if p.is_dir())
    for leftover in (p for p in scenes if p.name.startswith(".")):
        report.problems.append(f"{leftover.name}: an unfinished scene folder (a killed run; resume to finish it)")
    scenes = [p for p in scenes if not p.name.startswith(".")]
    _check_scene_count(root, split, {p.name for p in scenes}, report)
    if not scenes:
        report.problems.append(f"{split}: no scenes")
    for scene in tqdm(scenes, desc="validate", unit="scene"):
        gt, cams, infos = (read_json(scene / n) for n in ("scene_gt.json", "scene_camera.json", "scene_gt_info.json"))
        if not set(gt) == set(cams) == set(infos):
            report.problems.append(f"{scene.name}: scene_gt, scene_camera and scene_gt_info hold different images")
            continue
        for im_id in sorted(gt, key=int)[:max_images]:
            try:
                _check_image(scene, int(im_id), gt[im_id], cams[im_id], infos[im_id], models, report,
                             min_mask_px=min_mask_px, min_iou=min_iou, boundary_px=boundary_px,
                             max_depth_mm=max_depth_mm, depth_px=depth_px,
                             min_visible_px=min_visible_px)
            except (ValueError, KeyError, TypeError) as exc:
                report.problems.append(f"{scene.name}/{int(im_id):06d}: {exc}")
        for name in ("scene_gt_coco.json", "scene_gt_coco_modal.json"):
            if (scene / name).is_file():
                annotations = read_json(scene / name).get("annotations", [])
                expected = coco_instance_count(infos)
                if len(annotations) != expected:
                    report.problems.append(f"{scene.name}: {name} has {len(annotations)} annotations for "
                                           f"{expected} instances with visible pixels")
    return report

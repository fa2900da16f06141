"""COCO instance annotations of a BOP scene, as bop_toolkit's ``calc_gt_coco.py`` writes them.

``scene_gt_coco.json`` carries the amodal box (the full mask's, inside the image) and
``scene_gt_coco_modal.json`` the visible one; both hold the visible mask as an uncompressed RLE and the
visible pixel count as ``area``. Instances without a visible pixel are left out; annotation ids count the
written instances of the scene from 1 (pycocotools reads id 0 as "no match"); an instance seen less than
10 % is marked ``ignore``. Categories are every object of the dataset, named by their obj_id.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_VISIB_FRACT = 0.1  # below this an annotation is marked ignore


@dataclass
class CocoInstance:
    """One ground-truth instance: image id, obj_id, its full and visible masks [H, W] bool, visib_fract."""

    im_id: int
    obj_id: int
    mask: np.ndarray
    mask_visib: np.ndarray
    visib_fract: float


def rle(mask: np.ndarray) -> dict:
    """Uncompressed COCO run-length encoding of a binary mask [H, W]: run lengths over the column-major
    pixel order, starting with a (possibly empty) run of zeros; {"counts": [...], "size": [H, W]}."""
    flat = np.asarray(mask, dtype=bool).ravel(order="F")
    changes = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    counts = np.diff(np.concatenate([[0], changes, [flat.size]])).tolist()
    if flat.size and flat[0]:
        counts = [0] + counts
    return {"counts": [int(c) for c in counts], "size": [int(mask.shape[0]), int(mask.shape[1])]}


def mask_box(mask: np.ndarray) -> list[int]:
    """[x, y, w, h] (px) of the True pixels of a non-empty mask [H, W]."""
    ys, xs = np.nonzero(mask)
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min()) + 1, int(ys.max() - ys.min()) + 1]


def scene_coco(obj_ids: list[int], dataset_name: str, images: list[dict], instances: list[CocoInstance],
               modal: bool) -> dict:
    """One scene's COCO file. images: [{"id", "file_name" (relative to the scene folder), "width",
    "height"}]; ``modal``: boxes of the visible masks (scene_gt_coco_modal.json) instead of the full ones."""
    annotations = []
    for inst in instances:
        if not inst.mask_visib.any():
            continue
        height, width = inst.mask_visib.shape
        annotations.append({
            "id": len(annotations) + 1, "image_id": int(inst.im_id), "category_id": int(inst.obj_id), "iscrowd": 0,
            "area": int(np.count_nonzero(inst.mask_visib)),
            "bbox": mask_box(inst.mask_visib if modal else inst.mask), "segmentation": rle(inst.mask_visib),
            "width": int(width), "height": int(height), "ignore": bool(inst.visib_fract < MIN_VISIB_FRACT)})
    return {"info": {"description": dataset_name, "version": "1.0"}, "licenses": [],
            "categories": [{"id": int(i), "name": str(i), "supercategory": dataset_name} for i in sorted(obj_ids)],
            "images": images, "annotations": annotations}

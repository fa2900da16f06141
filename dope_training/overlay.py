"""Detected poses drawn on their image and written out (``pegasus infer``, inference_node's ``overlay``)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from dope_training.checkpoint import TargetObject
from dope_training.infer import DopeModel, ObjectPose
from pegasus_gen.formats.drawing import draw_instance
from pegasus_gen.io import images
from pegasus_gen.io.files import write_atomic

POSE_COLOUR = (255, 60, 200)
REFINED_COLOUR = (60, 200, 255)
KEYPOINT_COLOUR = (255, 255, 0)


def draw_poses(image: np.ndarray, K: np.ndarray, poses: list[ObjectPose], obj: TargetObject) -> np.ndarray:
    """A copy of ``image`` [H, W, 3] uint8 RGB with, per pose, the object's model box and axes at T_cam_obj
    (K [3, 3] px), its found keypoints (px) as dots and the label "name score"; where depth refinement
    accepted the pose, the refined box too (labelled "refined"; alone when PnP gave no pose)."""
    overlay = image.copy()
    for pose in poses:
        if pose.T is not None:
            draw_instance(overlay, K, pose.T, np.array(obj.bbox_min), np.array(obj.bbox_size), None, None,
                          POSE_COLOUR, f"{obj.name} {pose.score:.2f}")
        if pose.refined is not None:
            draw_instance(overlay, K, pose.refined, np.array(obj.bbox_min), np.array(obj.bbox_size), None, None,
                          REFINED_COLOUR, "refined" if pose.T is not None else f"refined {obj.name} {pose.score:.2f}")
        for x, y in pose.keypoints[np.isfinite(pose.keypoints).all(1)]:
            cv2.circle(overlay, (int(round(x)), int(round(y))), 3, KEYPOINT_COLOUR, -1, cv2.LINE_AA)
    return overlay


def write_poses(out: str | Path, image_path: str | Path, image: np.ndarray, K: np.ndarray, poses: list[ObjectPose],
                model: DopeModel, ms: float) -> tuple[Path, Path]:
    """``out``/STEM_poses.png (``draw_poses`` on ``image`` [H, W, 3] uint8 RGB) and ``out``/STEM_poses.json
    (image, model, backend, object, obj_id, K [3, 3] px, ms of inference, instances: ``ObjectPose.to_json``),
    STEM being ``image_path``'s; returns both paths."""
    out, stem, obj = Path(out), Path(image_path).stem, model.object
    png = images.write_image(out / f"{stem}_poses.png", draw_poses(image, K, poses, obj))
    doc = {"image": str(image_path), "model": str(model.path), "backend": model.backend, "object": obj.name,
           "obj_id": obj.obj_id, "K": K.tolist(), "ms": ms, "instances": [p.to_json() for p in poses]}
    path = write_atomic(out / f"{stem}_poses.json", lambda f: f.write(json.dumps(doc, indent=1).encode()))
    return png, path

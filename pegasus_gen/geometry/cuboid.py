"""DOPE's 9 keypoints of an object: the 8 corners of its model's bounding box and the box centre."""

from __future__ import annotations

import numpy as np

# corner signs in DOPE/NVISII order (object frame: x forward, y left, z up)
CORNER_SIGNS = np.array([[1, -1, 1], [-1, -1, 1], [-1, 1, 1], [1, 1, 1],
                         [1, -1, -1], [-1, -1, -1], [-1, 1, -1], [1, 1, -1]], dtype=np.float64)


def cuboid_points(bbox_min, bbox_size) -> np.ndarray:
    """[9, 3] keypoints (object frame, units of the input): corners 0..7 in DOPE's order, then the centre."""
    centre = np.asarray(bbox_min, dtype=np.float64) + 0.5 * np.asarray(bbox_size, dtype=np.float64)
    half = 0.5 * np.asarray(bbox_size, dtype=np.float64)
    return np.concatenate([centre + CORNER_SIGNS * half, centre[None]], axis=0)


def project_points(points_obj: np.ndarray, T_cam_obj: np.ndarray, K: np.ndarray) -> np.ndarray:
    """[N, 2] pixel coordinates (OpenCV pinhole, pixel centres at integers) of [N, 3] object-frame points."""
    p = np.asarray(points_obj, dtype=np.float64) @ T_cam_obj[:3, :3].T + T_cam_obj[:3, 3]
    uv = p @ np.asarray(K, dtype=np.float64).T
    return uv[:, :2] / uv[:, 2:3]

"""Pose errors of an estimate against the truth, from the object model's points (as bop_toolkit's pose_error).

ADD (Hinterstoisser et al.): the mean distance between the model's points under the estimated and the true
pose. ADD-S: the mean distance from each point under the true pose to the nearest point under the estimated
pose (for symmetric objects: a turn that maps the model onto itself costs nothing).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def transform_points(points: np.ndarray, T: np.ndarray) -> np.ndarray:
    """[N, 3] ``points`` (model frame) moved by the pose T [4, 4] (T_frame_model), same units."""
    return points @ T[:3, :3].T + T[:3, 3]


def add_error(points: np.ndarray, T_est: np.ndarray, T_gt: np.ndarray) -> float:
    """ADD in the points' units (metres for metric models): ``points`` [N, 3] in the model frame, the poses
    T_est and T_gt [4, 4] (T_cam_model, translation in the points' units)."""
    return float(np.linalg.norm(transform_points(points, T_est) - transform_points(points, T_gt), axis=1).mean())


def adds_error(points: np.ndarray, T_est: np.ndarray, T_gt: np.ndarray) -> float:
    """ADD-S in the points' units: ``points`` [N, 3] in the model frame, poses [4, 4] as for ``add_error``;
    for each true-pose point the distance to the nearest estimated-pose point, averaged."""
    return float(cKDTree(transform_points(points, T_est)).query(transform_points(points, T_gt))[0].mean())

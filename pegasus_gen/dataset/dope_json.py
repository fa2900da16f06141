"""DOPE/NDDS per-image annotation json (what DOPE's own training code reads), written next to each image.

Units follow NDDS (DOPE's original data): ``location`` in centimetres in the camera frame (OpenCV axes),
``quaternion_xyzw`` the object's orientation in the camera frame, ``projected_cuboid`` the 9 keypoints
(8 corners of the model's bounding box in DOPE's order, then its centre) in pixels.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from pegasus_gen.geometry.cuboid import cuboid_points, project_points


def dope_object(name: str, obj_id: int, T_cam_obj: np.ndarray, bbox_min: np.ndarray, bbox_size: np.ndarray,
                K: np.ndarray, visibility: float) -> dict:
    """One ``objects`` entry: T_cam_obj [4, 4] (m), the model's bounding box min corner and size [3] (m,
    object frame), K [3, 3], visibility = BOP visib_fract."""
    cuboid = cuboid_points(bbox_min, bbox_size)
    return {"class": name, "obj_id": int(obj_id), "visibility": float(visibility),
            "location": [float(v) * 100.0 for v in T_cam_obj[:3, 3]],
            "quaternion_xyzw": [float(v) for v in Rotation.from_matrix(T_cam_obj[:3, :3]).as_quat()],
            "cuboid_centroid": [float(v) * 100.0 for v in T_cam_obj[:3, :3] @ cuboid[8] + T_cam_obj[:3, 3]],
            "projected_cuboid": [[float(u), float(v)] for u, v in project_points(cuboid, T_cam_obj, K)]}


def dope_image(K: np.ndarray, width: int, height: int, objects: list[dict]) -> dict:
    """The per-image json: camera intrinsics and size, and the ``dope_object`` entries."""
    return {"camera_data": {"intrinsics": {"fx": float(K[0, 0]), "fy": float(K[1, 1]),
                                           "cx": float(K[0, 2]), "cy": float(K[1, 2])},
                            "width": int(width), "height": int(height)},
            "objects": objects}

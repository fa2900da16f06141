"""DOPE/NDDS per-image annotation json (what DOPE's own training code reads), written next to each image.

Units follow NDDS (DOPE's original data): ``location`` in centimetres in the camera frame (OpenCV axes),
``quaternion_xyzw`` the object's orientation in the camera frame, ``projected_cuboid`` the 9 keypoints
(8 corners of the model's bounding box in DOPE's order, then its centre) in pixels. The keys of DOPE's
NVISII exporter are there too: ``name``, ``px_count_all``/``px_count_visib``, the visible box
``bounding_box_minx_maxx_miny_maxy`` (px), and world-frame poses (``local_to_world_matrix``, the camera's
``camera_view_matrix``; translations in cm). Only instances with visible pixels are written.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from pegasus_gen.geometry.cuboid import cuboid_points, project_points


def _cm(T: np.ndarray) -> list[list[float]]:
    """4x4 transform (m) as nested lists with its translation in cm."""
    out = np.array(T, dtype=np.float64)
    out[:3, 3] *= 100.0
    return out.tolist()


def dope_object(name: str, obj_id: int, index: int, T_cam_obj: np.ndarray, T_world_obj: np.ndarray,
                bbox_min: np.ndarray, bbox_size: np.ndarray, K: np.ndarray, gt_info: dict) -> dict:
    """One ``objects`` entry for instance ``index`` of the image (its scene_gt index): T_cam_obj and
    T_world_obj [4, 4] (m), the model's bounding box min corner and size [3] (m, object frame), K [3, 3],
    and the instance's BOP gt_info (visib_fract, px counts, bbox_visib)."""
    cuboid = cuboid_points(bbox_min, bbox_size)
    x, y, w, h = gt_info["bbox_visib"]
    return {"class": name, "name": f"{name}_{index:03d}", "obj_id": int(obj_id),
            "visibility": float(gt_info["visib_fract"]),
            "px_count_all": int(gt_info["px_count_all"]), "px_count_visib": int(gt_info["px_count_visib"]),
            "bounding_box_minx_maxx_miny_maxy": [int(x), int(x + w), int(y), int(y + h)],
            "location": [float(v) * 100.0 for v in T_cam_obj[:3, 3]],
            "quaternion_xyzw": [float(v) for v in Rotation.from_matrix(T_cam_obj[:3, :3]).as_quat()],
            "local_to_world_matrix": _cm(T_world_obj),
            "cuboid_centroid": [float(v) * 100.0 for v in T_cam_obj[:3, :3] @ cuboid[8] + T_cam_obj[:3, 3]],
            "projected_cuboid": [[float(u), float(v)] for u, v in project_points(cuboid, T_cam_obj, K)]}


def dope_image(K: np.ndarray, T_cam_world: np.ndarray, width: int, height: int, objects: list[dict]) -> dict:
    """The per-image json: camera intrinsics, size and view matrix (world -> camera), and the ``dope_object``
    entries."""
    return {"camera_data": {"intrinsics": {"fx": float(K[0, 0]), "fy": float(K[1, 1]),
                                           "cx": float(K[0, 2]), "cy": float(K[1, 2])},
                            "width": int(width), "height": int(height), "camera_view_matrix": _cm(T_cam_world)},
            "objects": objects}

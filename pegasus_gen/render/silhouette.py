"""Mesh silhouettes: the pixels a triangle mesh covers in an OpenCV pinhole camera (no shading, no depth)."""

from __future__ import annotations

import cv2
import numpy as np

_SUBPIXEL_BITS = 4


def mesh_silhouette(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, T_cam_world: np.ndarray,
                    width: int, height: int) -> np.ndarray:
    """[H, W] bool mask of pixels (centres at integer coordinates) inside any projected triangle.

    vertices [V, 3] world (m), faces [F, 3] int; every vertex must lie in front of the camera.
    """
    v = np.asarray(vertices, dtype=np.float64) @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    if (v[:, 2] <= 1e-6).any():
        raise ValueError("mesh_silhouette: some vertices are behind the camera")
    uv = (v[:, :2] / v[:, 2:3]) * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    pts = np.round(uv[np.asarray(faces)] * (1 << _SUBPIXEL_BITS)).astype(np.int32)
    mask = np.zeros((height, width), np.uint8)
    for tri in pts:  # one by one: fillPoly on many polygons would XOR their overlaps
        cv2.fillConvexPoly(mask, tri, 255, lineType=cv2.LINE_8, shift=_SUBPIXEL_BITS)
    return mask > 0


def mesh_coverage(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, T_cam_world: np.ndarray, width: int,
                  height: int, supersample: int = 8) -> np.ndarray:
    """[H, W] share in [0, 1] of each pixel the mesh covers: its silhouette at ``supersample`` times the
    resolution (same pixel-centre convention), averaged over each pixel's block. Arguments as ``mesh_silhouette``."""
    s = supersample
    K_fine = np.diag([s, s, 1.0]) @ K + np.array([[0, 0, (s - 1) / 2], [0, 0, (s - 1) / 2], [0, 0, 0]])
    fine = mesh_silhouette(vertices, faces, K_fine, T_cam_world, width * s, height * s)
    return fine.reshape(height, s, width, s).mean(axis=(1, 3))

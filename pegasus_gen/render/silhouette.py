"""Mesh silhouettes: the pixels a triangle mesh covers in an OpenCV pinhole camera (no shading, no depth).

A pixel is covered when its centre (integer image coordinates) lies inside or on the edge of a projected
triangle: the exact point-sampling rule, so the silhouette's outline neither grows nor shrinks with the
resolution (a conservative polygon fill, such as OpenCV's, adds up to half a pixel around it: 1.5 % of the
size of an object 65 px across).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def _fill_triangles(uv: np.ndarray, faces: np.ndarray, mask: np.ndarray) -> None:
    """Set ``mask`` [H, W] uint8 to 1 at the pixel centres inside or on any triangle ``faces`` [F, 3] of the
    image points ``uv`` [V, 2] (px); triangles of either winding, degenerate ones cover nothing."""
    height, width = mask.shape
    for f in range(faces.shape[0]):
        x0, y0 = uv[faces[f, 0], 0], uv[faces[f, 0], 1]
        x1, y1 = uv[faces[f, 1], 0], uv[faces[f, 1], 1]
        x2, y2 = uv[faces[f, 2], 0], uv[faces[f, 2], 1]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if area == 0.0:
            continue
        if area < 0.0:  # one winding: every edge function is >= 0 inside
            x1, y1, x2, y2 = x2, y2, x1, y1
        u_lo = max(math.ceil(min(x0, x1, x2)), 0)
        u_hi = min(math.floor(max(x0, x1, x2)), width - 1)
        v_lo = max(math.ceil(min(y0, y1, y2)), 0)
        v_hi = min(math.floor(max(y0, y1, y2)), height - 1)
        for v in range(v_lo, v_hi + 1):
            for u in range(u_lo, u_hi + 1):
                if ((x1 - x0) * (v - y0) - (y1 - y0) * (u - x0) >= 0.0
                        and (x2 - x1) * (v - y1) - (y2 - y1) * (u - x1) >= 0.0
                        and (x0 - x2) * (v - y2) - (y0 - y2) * (u - x2) >= 0.0):
                    mask[v, u] = 1


def mesh_silhouette(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, T_cam_world: np.ndarray,
                    width: int, height: int) -> np.ndarray:
    """[H, W] bool mask of pixels whose centres (integer coordinates) lie inside or on a projected triangle.

    vertices [V, 3] world (m), faces [F, 3] int; every vertex must lie in front of the camera.
    """
    v = np.asarray(vertices, dtype=np.float64) @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    if (v[:, 2] <= 1e-6).any():
        raise ValueError("mesh_silhouette: some vertices are behind the camera")
    uv = (v[:, :2] / v[:, 2:3]) * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    mask = np.zeros((height, width), np.uint8)
    _fill_triangles(np.ascontiguousarray(uv), np.ascontiguousarray(faces, dtype=np.int64), mask)
    return mask > 0


def mesh_coverage(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, T_cam_world: np.ndarray, width: int,
                  height: int, supersample: int = 8) -> np.ndarray:
    """[H, W] share in [0, 1] of each pixel the mesh covers: its silhouette at ``supersample`` times the
    resolution (same pixel-centre convention), averaged over each pixel's block. Arguments as ``mesh_silhouette``."""
    s = supersample
    K_fine = np.diag([s, s, 1.0]) @ K + np.array([[0, 0, (s - 1) / 2], [0, 0, (s - 1) / 2], [0, 0, 0]])
    fine = mesh_silhouette(vertices, faces, K_fine, T_cam_world, width * s, height * s)
    return fine.reshape(height, s, width, s).mean(axis=(1, 3))

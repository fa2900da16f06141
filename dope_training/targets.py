"""DOPE's training targets at the network's output stride: belief maps and affinity fields.

Map convention (``cells_to_pixels``; the decoder uses it as the exact inverse): output cell (i, j) covers input pixels
[j*s, (j+1)*s) x [i*s, (i+1)*s); its centre is at input pixel ((j + 0.5) s - 0.5, (i + 0.5) s - 0.5)
with pixel centres at integer coordinates (OpenCV).
"""

from __future__ import annotations

import numpy as np

STRIDE = 8  # the network's output stride: one map cell per 8 x 8 input pixels
SIGMA_PX = 4.0  # belief Gaussian std in input pixels (half a map cell at stride 8), as DOPE
AFFINITY_RADIUS_PX = 8.0  # cells whose centre lies this close to a corner carry its affinity vector


def cells_to_pixels(cells, stride: int) -> np.ndarray:
    """Input-pixel coordinates of (fractional) output-cell coordinates, any shape: (c + 0.5) s - 0.5."""
    return (np.asarray(cells, dtype=np.float64) + 0.5) * stride - 0.5


def cell_centres(height: int, width: int, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """x, y [H/s, W/s]: input-pixel coordinates of the output cells' centres."""
    return np.meshgrid(cells_to_pixels(np.arange(width // stride), stride),
                       cells_to_pixels(np.arange(height // stride), stride))


def make_targets(keypoints: np.ndarray, valid: np.ndarray, height: int, width: int, stride: int = 8,
                 sigma_px: float = SIGMA_PX, radius_px: float = AFFINITY_RADIUS_PX) -> tuple[np.ndarray, np.ndarray]:
    """Belief and affinity targets for an input image of ``height`` x ``width`` px.

    keypoints [I, 9, 2]: per instance the 8 cuboid corners then the centroid, input pixels (x, y);
    valid [I, 9] bool: keypoints to draw. Returns beliefs [9, H/s, W/s] float32 (a Gaussian of std
    ``sigma_px`` around each keypoint, value 1 at it, max over instances) and affinities
    [16, H/s, W/s] float32 (channels 2k, 2k+1: unit vector x, y from corner k towards its instance's
    centroid, in the cells within ``radius_px`` of the corner; later instances overwrite).
    """
    cx, cy = cell_centres(height, width, stride)
    beliefs = np.zeros((9, *cx.shape), np.float32)
    affinities = np.zeros((16, *cx.shape), np.float32)
    for points, ok in zip(np.asarray(keypoints, np.float64), np.asarray(valid, bool)):
        for k in range(9):
            if not ok[k]:
                continue
            d2 = (cx - points[k, 0]) ** 2 + (cy - points[k, 1]) ** 2
            np.maximum(beliefs[k], np.exp(-d2 / (2 * sigma_px**2)), out=beliefs[k])
            if k == 8 or not ok[8]:
                continue
            direction = points[8] - points[k]
            norm = np.linalg.norm(direction)
            if norm < 1e-9:
                continue
            near = d2 <= radius_px**2
            affinities[2 * k][near] = direction[0] / norm
            affinities[2 * k + 1][near] = direction[1] / norm
    return beliefs, affinities

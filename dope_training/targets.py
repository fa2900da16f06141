"""DOPE's training targets at the network's output stride: belief maps, affinity fields and (for networks with a
distance head) distance codes around each centroid.

Map convention (``cells_to_pixels``; the decoder uses it as the exact inverse): output cell (i, j) covers input pixels
[j*s, (j+1)*s) x [i*s, (i+1)*s); its centre is at input pixel ((j + 0.5) s - 0.5, (i + 0.5) s - 0.5)
with pixel centres at integer coordinates (OpenCV).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import map_coordinates

STRIDE = 8  # the network's output stride: one map cell per 8 x 8 input pixels
SIGMA_PX = 4.0  # belief Gaussian std in input pixels (half a map cell at stride 8), as DOPE
AFFINITY_RADIUS_PX = 8.0  # cells whose centre lies this close to a corner carry its affinity vector
MIN_KEYPOINTS = 5  # object points besides the centre a network's maps hold at least (pnp.SAMPLE's draws need 5)
# distance codes: the log of the distance (m) at which a camera of this focal length (px) would see the object as
# large as the network sees it, so that a code does not depend on the crop's scale
DISTANCE_REF_PX = 500.0


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

    keypoints [I, K + 1, 2]: per instance the K object points (DOPE's: the 8 cuboid corners) then the centroid,
    input pixels (x, y); valid [I, K + 1] bool: keypoints to draw. Returns beliefs [K + 1, H/s, W/s] float32 (a
    Gaussian of std ``sigma_px`` around each keypoint, value 1 at it, max over instances) and affinities
    [2 K, H/s, W/s] float32 (channels 2k, 2k+1: unit vector x, y from point k towards its instance's centroid,
    in the cells within ``radius_px`` of the point; later instances overwrite).
    """
    keypoints = np.asarray(keypoints, np.float64)
    count = keypoints.shape[1]  # K + 1
    cx, cy = cell_centres(height, width, stride)
    beliefs = np.zeros((count, *cx.shape), np.float32)
    affinities = np.zeros((2 * (count - 1), *cx.shape), np.float32)
    for points, ok in zip(keypoints, np.asarray(valid, bool)):
        for k in range(count):
            if not ok[k]:
                continue
            d2 = (cx - points[k, 0]) ** 2 + (cy - points[k, 1]) ** 2
            np.maximum(beliefs[k], np.exp(-d2 / (2 * sigma_px**2)), out=beliefs[k])
            if k == count - 1 or not ok[-1]:
                continue
            direction = points[-1] - points[k]
            norm = np.linalg.norm(direction)
            if norm < 1e-9:
                continue
            near = d2 <= radius_px**2
            affinities[2 * k][near] = direction[0] / norm
            affinities[2 * k + 1][near] = direction[1] / norm
    return beliefs, affinities


def read_map(values: np.ndarray, point_px, stride: int) -> float:
    """One map [h, w] read at input pixel ``point_px`` (x, y): bilinear between the cell centres
    (``cells_to_pixels``'s inverse), the border cells' values beyond them."""
    x, y = (np.asarray(point_px, np.float64) + 0.5) / stride - 0.5
    return float(map_coordinates(np.asarray(values, np.float64), [[y], [x]], order=1, mode="nearest")[0])


def mapped_focal(K: np.ndarray, linear: np.ndarray) -> float:
    """The focal length (px) of camera K [3, 3] after its image is mapped by ``linear`` [2, 2] (the linear part
    of the image-to-network-input map: a crop's affine, a resize's diag(sx, sy)): sqrt(fx fy |det|)."""
    return float(np.sqrt(K[0, 0] * K[1, 1] * abs(np.linalg.det(linear))))


def distance_code(z_m, focal_px: float) -> np.ndarray:
    """The distance code of an object whose centre lies ``z_m`` (m, along the optical axis; any shape) from a
    camera of ``focal_px`` (px, the network input's): log(z * DISTANCE_REF_PX / focal_px)."""
    return np.log(np.asarray(z_m, np.float64) * DISTANCE_REF_PX / focal_px)


def distance_from_code(code, focal_px: float) -> np.ndarray:
    """The inverse of ``distance_code``: metres from codes (any shape) read off a network input of ``focal_px``."""
    return np.exp(np.asarray(code, np.float64)) * focal_px / DISTANCE_REF_PX


def off_axis_factor(rays_xy) -> np.ndarray:
    """sqrt(cos theta) [...] of rays [..., 2] (normalised image coordinates x / z, y / z) theta off the optical
    axis. An object off the axis looks larger than on it at the same depth z: its image is stretched 1 / cos theta
    along the radial direction (1 along the tangential), so its area grows 1 / cos theta and its size
    1 / sqrt(cos theta). The distance head of a network with ``ModelConfig.distance_off_axis`` learns the depth at
    which the object would look as large on the axis, z x this factor: a function of its look alone, which a crop
    shows without where in the image it came from (a network taught z itself reads objects far off the axis as
    nearer and those on it as farther)."""
    rays = np.asarray(rays_xy, np.float64)
    return (1.0 + np.sum(rays * rays, axis=-1)) ** -0.25


def make_distance_targets(centroids: np.ndarray, codes: np.ndarray, height: int, width: int, stride: int = 8,
                          sigma_px: float = SIGMA_PX) -> tuple[np.ndarray, np.ndarray]:
    """The distance head's target and its weight, each [1, H/s, W/s] float32, for an input image of ``height`` x
    ``width`` px. centroids [I, 2]: each instance's centroid (input px, x, y); codes [I]: its ``distance_code``
    (NaN: unknown, no target). Each cell takes the code of the instance whose centroid belief (a Gaussian of std
    ``sigma_px``, as ``make_targets``) is highest there, weighted by that belief: the head is taught where the
    centroid's belief is, and read there."""
    cx, cy = cell_centres(height, width, stride)
    target = np.zeros((1, *cx.shape), np.float32)
    weight = np.zeros((1, *cx.shape), np.float32)
    for (x, y), code in zip(np.asarray(centroids, np.float64).reshape(-1, 2), np.asarray(codes, np.float64)):
        if not np.isfinite(code):
            continue
        belief = np.exp(-((cx - x) ** 2 + (cy - y) ** 2) / (2 * sigma_px**2))
        higher = belief > weight[0]
        target[0][higher] = code
        weight[0][higher] = belief[higher]
    return target, weight

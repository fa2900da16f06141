"""Colour transforms of splats (gains, hue turns, shading, blends towards a texture), exact on every SH band, and
highlights added to their colour.

A splat's colour seen from direction d is C0 * DC + 0.5 + sum of the higher bands' terms. A linear map M of
that colour, c' = M c, is DC' = (M (C0 DC + 0.5) - 0.5) / C0 and, each higher coefficient being a colour,
coefficient' = M coefficient.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from pegasus_gen.splats.cloud import SplatCloud, quat_wxyz_to_rotation
from pegasus_gen.splats.sh import rgb_to_sh_dc, sh_dc_to_rgb


def transform_colour(cloud: SplatCloud, M: np.ndarray) -> SplatCloud:
    """The cloud with its colour mapped by ``M``: [3, 3] for every splat, or [N, 3, 3] per splat."""
    M = np.asarray(M, np.float64)
    sh = cloud.sh.astype(np.float64)
    colour = sh_dc_to_rgb(sh[:, 0])
    if M.ndim == 2:  # one matrix: one product (an environment's 400 k splats in a third of the einsum's time)
        out = (sh.reshape(-1, 3) @ M.T).reshape(sh.shape)
        out[:, 0] = rgb_to_sh_dc(colour @ M.T)
    else:
        out = np.einsum("nij,nkj->nki", M, sh)
        out[:, 0] = rgb_to_sh_dc(np.einsum("nij,nj->ni", M, colour))
    return cloud.replace(sh=out)


def hue_rotation(degrees: float) -> np.ndarray:
    """[3, 3] rotation of RGB colours about the grey axis (1, 1, 1) by ``degrees``: hue turns, grey stays
    grey, brightness (the mean of R, G, B) is kept."""
    a = np.radians(degrees)
    k = np.full(3, 1 / np.sqrt(3))
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def blend_colour(cloud: SplatCloud, rgb: np.ndarray, weight: float) -> SplatCloud:
    """The cloud with its colour blended towards ``rgb`` [N, 3] (0..1, view-independent) by ``weight`` (0: as
    it was, 1: ``rgb`` seen from every direction): c' = (1 - w) c + w rgb on every band."""
    sh = cloud.sh.astype(np.float64)
    colour = (1.0 - weight) * sh_dc_to_rgb(sh[:, 0]) + weight * np.asarray(rgb, np.float64)
    sh[:, 1:] *= 1.0 - weight
    sh[:, 0] = rgb_to_sh_dc(colour)
    return cloud.replace(sh=sh)


def splat_normals(cloud: SplatCloud, centre: np.ndarray) -> np.ndarray:
    """[N, 3] unit normals: each splat's axis of least extent (a surface splat lies flat on its surface), turned
    to point away from ``centre`` [3] (the object's centre, same frame: right on convex shapes)."""
    R = quat_wxyz_to_rotation(cloud.quats_wxyz)
    n = np.take_along_axis(R, np.argmin(cloud.log_scales, axis=1)[:, None, None], axis=2)[..., 0]
    return np.where(np.sum(n * (cloud.means - centre), axis=1, keepdims=True) < 0, -n, n)


def shade_lambert(cloud: SplatCloud, centre: np.ndarray, light: np.ndarray, ambient: float,
                  gain: float = 1.5) -> SplatCloud:
    """The cloud lit by a distant light from direction ``light`` [3] (towards the light, same frame): each
    splat's colour times ambient + (1 - ambient) * gain * max(0, n . light), n its normal (``splat_normals``
    about ``centre`` [3]); a splat facing away keeps ``ambient`` of its colour."""
    light = np.asarray(light, np.float64) / np.linalg.norm(light)
    lit = np.maximum(splat_normals(cloud, np.asarray(centre, np.float64)) @ light, 0.0)
    factor = ambient + (1.0 - ambient) * gain * lit
    return transform_colour(cloud, factor[:, None, None] * np.eye(3))


def smooth_normals(cloud: SplatCloud, centre: np.ndarray, neighbours: int = 48) -> np.ndarray:
    """[N, 3] unit normals: ``splat_normals`` about ``centre`` [3] averaged over each splat's ``neighbours`` nearest
    splats (the splat itself among them): a scanned surface's small bumps smoothed away, as a highlight on a smooth
    real surface shows it."""
    n = splat_normals(cloud, np.asarray(centre, np.float64))
    k = min(neighbours, len(cloud))
    if k <= 1:
        return n
    _, idx = cKDTree(cloud.means).query(cloud.means, k)
    mean = n[idx].sum(axis=1)
    length = np.linalg.norm(mean, axis=1, keepdims=True)
    return np.where(length > 1e-9, mean / np.maximum(length, 1e-9), n)


def shade_specular(cloud: SplatCloud, normals: np.ndarray, light: np.ndarray, eye: np.ndarray, strength: float,
                   shininess: float) -> SplatCloud:
    """The cloud with the highlight of a distant white light from direction ``light`` [3] (towards the light) seen
    from ``eye`` [3] (the camera's centre, same frame) added to each splat's colour, the same on every channel:
    strength * max(0, n . h)^shininess (Blinn-Phong; h the unit half-way vector between the light and the
    direction to the eye, n the splat's unit normal, ``normals`` [N, 3]), none on a splat facing away from the
    light. View-dependent: recomputed for every camera."""
    light = np.asarray(light, np.float64) / np.linalg.norm(light)
    to_eye = np.asarray(eye, np.float64) - cloud.means
    half = to_eye / np.linalg.norm(to_eye, axis=1, keepdims=True) + light
    half /= np.maximum(np.linalg.norm(half, axis=1, keepdims=True), 1e-12)  # zero only with the eye opposite the light
    highlight = strength * np.maximum(np.sum(normals * half, axis=1), 0.0) ** shininess * (normals @ light > 0)
    sh = cloud.sh.astype(np.float64)
    sh[:, 0] = rgb_to_sh_dc(sh_dc_to_rgb(sh[:, 0]) + highlight[:, None])
    return cloud.replace(sh=sh)

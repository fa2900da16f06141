"""Real spherical harmonics in the 3DGS convention (INRIA / gsplat), degrees 0..3, and their rotation.

Coefficient layout everywhere: ``sh[N, K, 3]`` with ``K = (degree + 1) ** 2``; index 0 is the DC term.
A splat's colour seen along the unit direction ``d`` (from the camera centre to the splat, world frame)
is ``max(basis(d) @ sh + 0.5, 0)``.
"""

from __future__ import annotations

import numba
import numpy as np

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)

MAX_DEGREE = 3


def num_coeffs(degree: int) -> int:
    """Number of SH coefficients per channel for ``degree``: (degree + 1)^2."""
    return (degree + 1) ** 2


def degree_from_num_coeffs(k: int) -> int:
    """Inverse of :func:`num_coeffs`; raises ValueError when ``k`` is not 1, 4, 9 or 16."""
    for degree in range(MAX_DEGREE + 1):
        if num_coeffs(degree) == k:
            return degree
    raise ValueError(f"{k} SH coefficients per channel is not (degree+1)^2 for a degree in 0..{MAX_DEGREE}")


@numba.njit(cache=True, inline="always")
def basis_into(x, y, z, k, out):
    """Write the first ``k`` (1, 4, 9 or 16) basis values at unit direction (x, y, z) into ``out[:k]``."""
    out[0] = C0
    if k <= 1:
        return
    out[1] = -C1 * y
    out[2] = C1 * z
    out[3] = -C1 * x
    if k <= 4:
        return
    xx = x * x
    yy = y * y
    zz = z * z
    out[4] = C2[0] * x * y
    out[5] = C2[1] * y * z
    out[6] = C2[2] * (2.0 * zz - xx - yy)
    out[7] = C2[3] * x * z
    out[8] = C2[4] * (xx - yy)
    if k <= 9:
        return
    out[9] = C3[0] * y * (3.0 * xx - yy)
    out[10] = C3[1] * x * y * z
    out[11] = C3[2] * y * (4.0 * zz - xx - yy)
    out[12] = C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
    out[13] = C3[4] * x * (4.0 * zz - xx - yy)
    out[14] = C3[5] * z * (xx - yy)
    out[15] = C3[6] * x * (xx - 3.0 * yy)


@numba.njit(cache=True)
def _basis_rows(dirs, k):
    out = np.empty((dirs.shape[0], k), dtype=np.float64)
    for i in range(dirs.shape[0]):
        basis_into(dirs[i, 0], dirs[i, 1], dirs[i, 2], k, out[i])
    return out


def basis(dirs: np.ndarray, degree: int) -> np.ndarray:
    """SH basis values. dirs: [M, 3] directions (normalised here). Returns [M, (degree+1)^2] float64."""
    d = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    return _basis_rows(np.ascontiguousarray(d), num_coeffs(degree))


def evaluate(sh: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Raw SH value (before the +0.5 offset and clamp). sh: [N, K, 3]; dirs: [N, 3]. Returns [N, 3]."""
    b = basis(dirs, degree_from_num_coeffs(sh.shape[1]))
    return np.einsum("nk,nkc->nc", b, sh.astype(np.float64))


def rgb_to_sh_dc(rgb: np.ndarray) -> np.ndarray:
    """DC coefficient for a view-independent colour: (rgb - 0.5) / C0. rgb: [..., 3] in [0, 1]."""
    return (np.asarray(rgb, dtype=np.float64) - 0.5) / C0


def sh_dc_to_rgb(dc: np.ndarray) -> np.ndarray:
    """The view-independent colour of DC coefficients [..., 3]: C0 dc + 0.5 (unclamped; the dtype of ``dc``)."""
    return C0 * np.asarray(dc) + 0.5


def _fibonacci_sphere(n: int) -> np.ndarray:
    """n well-spread unit directions [n, 3] (deterministic)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (1.0 + 5.0**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


_FIT_DIRS = _fibonacci_sphere(64)


def band_rotation_matrices(rotation: np.ndarray, degree: int) -> list[np.ndarray]:
    """Per-band SH rotation matrices for a 3x3 rotation R, bands 1..degree.

    Band l's matrix M_l [(2l+1), (2l+1)] satisfies basis_l(R^T d) = basis_l(d) @ M_l for every d,
    so coefficients c_l [(2l+1), 3] become M_l @ c_l and eval(c', d) == eval(c, R^T d).
    Built by an exact least-squares fit on 64 spread directions (the band spans are rotation
    invariant, so the fit has zero residual).
    """
    R = np.asarray(rotation, dtype=np.float64)
    y = basis(_FIT_DIRS, degree)
    y_rot = basis(_FIT_DIRS @ R, degree)  # rows are R^T d
    mats = []
    for band in range(1, degree + 1):
        sl = slice(band * band, (band + 1) * (band + 1))
        m, *_ = np.linalg.lstsq(y[:, sl], y_rot[:, sl], rcond=None)
        mats.append(m)
    return mats


def rotate(sh: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Rotate SH coefficients [N, K, 3] by a 3x3 rotation (a splat rotated by R). Returns float64 [N, K, 3].

    The DC band is unchanged; bands 1..3 are mixed so that eval(out, d) == eval(sh, R^T d).
    """
    degree = degree_from_num_coeffs(sh.shape[1])
    out = np.array(sh, dtype=np.float64, copy=True)
    for band, m in enumerate(band_rotation_matrices(rotation, degree), start=1):
        sl = slice(band * band, (band + 1) * (band + 1))
        out[:, sl, :] = np.einsum("ij,njc->nic", m, out[:, sl, :])
    return out

"""Flat Gaussians covering a surface: the splat form of sampled surface points (meshes, procedural shapes)."""

from __future__ import annotations

import numpy as np

from pegasus_gen.splats import sh as shlib
from pegasus_gen.splats.cloud import SplatCloud, quat_multiply_wxyz


def quats_z_to(normals: np.ndarray, spin: np.ndarray) -> np.ndarray:
    """wxyz quaternions [N, 4] turning +z onto each unit normal [N, 3], after a spin [N] (rad) about z."""
    n = np.asarray(normals, dtype=np.float64)
    q = np.concatenate([1.0 + n[:, 2:3], -n[:, 1:2], n[:, 0:1], np.zeros((len(n), 1))], axis=1)  # z x n
    flip = q[:, 0] < 1e-9  # n == -z: half turn about x
    q[flip] = [0.0, 1.0, 0.0, 0.0]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    spin_q = np.stack([np.cos(spin / 2), np.zeros_like(spin), np.zeros_like(spin), np.sin(spin / 2)], axis=1)
    return quat_multiply_wxyz(q, spin_q)


def surface_splats(points: np.ndarray, normals: np.ndarray, colors: np.ndarray, spacing: float,
                   rng: np.random.Generator, sh_degree: int = 3, view_dependence: float = 0.05,
                   opacity: float = 0.95, label: int = 0) -> SplatCloud:
    """Flat Gaussians on a surface.

    points, normals, colors [N, 3] (metres, unit, rgb in [0, 1]); spacing: mean distance between
    neighbouring samples (metres) sets the in-plane size; view_dependence: std of the higher SH bands.
    """
    n = len(points)
    k = shlib.num_coeffs(sh_degree)
    sh = np.zeros((n, k, 3))
    sh[:, 0, :] = shlib.rgb_to_sh_dc(colors)
    if k > 1:
        sh[:, 1:, :] = rng.normal(0.0, view_dependence, size=(n, k - 1, 3))
    tangent = spacing * rng.uniform(0.55, 0.8, size=(n, 2))
    scales = np.concatenate([tangent, np.full((n, 1), spacing * 0.05)], axis=1)
    quats = quats_z_to(normals, rng.uniform(0, 2 * np.pi, n))
    logit = np.log(opacity / (1.0 - opacity))
    return SplatCloud(points, quats, np.log(scales), np.full(n, logit), sh, np.full(n, label, np.int32))

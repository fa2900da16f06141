"""The Gaussian-splat cloud: arrays, rigid placement with exact SH rotation, composition, filters, PLY I/O.

A cloud holds N splats (all arrays share N):
- ``means`` [N, 3] float32, metres, in the cloud's frame (an object's cloud: its object frame),
- ``quats_wxyz`` [N, 4] float32, rotation of each Gaussian (not necessarily normalised),
- ``log_scales`` [N, 3] float32, natural log of the standard deviations (metres),
- ``opacity_logits`` [N] float32, opacity = sigmoid(logit),
- ``sh`` [N, K, 3] float32 SH coefficients, K = (degree+1)^2, degree 0..3 (gsplat layout),
- ``labels`` [N] int32 instance label (0 for an environment, obj/instance ids for objects).

Placement composes absolute poses: an object cloud stored in its object frame is placed with
``cloud.transformed(T_world_obj)`` for each new pose; the stored cloud is never modified.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from pegasus_gen.splats import sh as shlib


@dataclass(frozen=True, eq=False)
class SplatCloud:
    means: np.ndarray
    quats_wxyz: np.ndarray
    log_scales: np.ndarray
    opacity_logits: np.ndarray
    sh: np.ndarray
    labels: np.ndarray

    def __post_init__(self):
        n = np.asarray(self.means).shape[0] if np.ndim(self.means) == 2 else -1
        expected = {
            "means": (n, 3),
            "quats_wxyz": (n, 4),
            "log_scales": (n, 3),
            "opacity_logits": (n,),
            "labels": (n,),
        }
        for name, shape in expected.items():
            arr = np.asarray(getattr(self, name))
            if arr.shape != shape:
                raise ValueError(f"SplatCloud.{name} must have shape {shape}, got {arr.shape}")
        sh = np.asarray(self.sh)
        if sh.ndim != 3 or sh.shape[0] != n or sh.shape[2] != 3:
            raise ValueError(f"SplatCloud.sh must have shape ({n}, K, 3), got {sh.shape}")
        shlib.degree_from_num_coeffs(sh.shape[1])
        for name in ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh"):
            object.__setattr__(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.float32))
        object.__setattr__(self, "labels", np.ascontiguousarray(self.labels, dtype=np.int32))

    # ------------------------------------------------------------------ basics
    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return shlib.degree_from_num_coeffs(self.sh.shape[1])

    @property
    def opacities(self) -> np.ndarray:
        """[N] opacity in (0, 1)."""
        return 1.0 / (1.0 + np.exp(-self.opacity_logits.astype(np.float64)))

    @property
    def scales(self) -> np.ndarray:
        """[N, 3] standard deviations in metres."""
        return np.exp(self.log_scales.astype(np.float64))

    @classmethod
    def empty(cls, sh_degree: int = 0) -> "SplatCloud":
        k = shlib.num_coeffs(sh_degree)
        return cls(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, k, 3)),
                   np.zeros(0, np.int32))

    def replace(self, **arrays) -> "SplatCloud":
        """A new cloud with some arrays replaced."""
        fields = {name: getattr(self, name) for name in
                  ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh", "labels")}
        fields.update(arrays)
        return SplatCloud(**fields)

    def with_label(self, label: int) -> "SplatCloud":
        """The same splats, all carrying instance ``label``."""
        return self.replace(labels=np.full(len(self), label, dtype=np.int32))

    def with_sh_degree(self, degree: int) -> "SplatCloud":
        """Truncate or zero-pad the SH coefficients to ``degree`` (padding is exact: zero terms)."""
        k = shlib.num_coeffs(degree)
        sh = np.zeros((len(self), k, 3), dtype=np.float32)
        keep = min(k, self.sh.shape[1])
        sh[:, :keep] = self.sh[:, :keep]
        return self.replace(sh=sh)

    # -------------------------------------------------------------- placement
    def transformed(self, T: np.ndarray, scale: float = 1.0) -> "SplatCloud":
        """The cloud placed by the rigid transform T [4, 4] after a uniform ``scale``: x' = R (s x) + t.

        Each Gaussian's orientation is composed with R, log-scales gain log(s), and SH bands 1..3 are
        rotated exactly so view-dependent colour follows the rotation. Pass an absolute pose
        (e.g. T_world_obj for a cloud in its object frame), never an increment on an already placed cloud.
        """
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"transform must be a finite 4x4 matrix, got shape {T.shape}")
        R, t = T[:3, :3], T[:3, 3]
        if not is_rigid(T):
            raise ValueError("transform must be rigid: orthonormal rotation with det +1 and last row [0, 0, 0, 1]")
        if not (np.isfinite(scale) and scale > 0):
            raise ValueError(f"scale must be a positive number, got {scale}")
        means = self.means.astype(np.float64) * scale @ R.T + t
        quats = quat_multiply_wxyz(rotation_to_quat_wxyz(R), self.quats_wxyz.astype(np.float64))
        log_scales = self.log_scales.astype(np.float64) + np.log(scale)
        sh = shlib.rotate(self.sh, R) if self.sh_degree > 0 else self.sh
        return self.replace(means=means, quats_wxyz=quats, log_scales=log_scales, sh=sh)

    # -------------------------------------------------------------- filtering
    def select(self, mask: np.ndarray) -> "SplatCloud":
        """The splats where the boolean ``mask`` [N] (or an index array) selects."""
        return SplatCloud(self.means[mask], self.quats_wxyz[mask], self.log_scales[mask],
                          self.opacity_logits[mask], self.sh[mask], self.labels[mask])

    def crop_box(self, lower: Sequence[float], upper: Sequence[float]) -> "SplatCloud":
        """Splats whose centre lies in the axis-aligned box [lower, upper] (metres, this cloud's frame)."""
        lo, hi = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
        return self.select(np.all((self.means >= lo) & (self.means <= hi), axis=1))

    def filter_opacity(self, min_opacity: float) -> "SplatCloud":
        """Splats with opacity >= ``min_opacity``."""
        return self.select(self.opacities >= min_opacity)

    def filter_labels(self, labels: Sequence[int]) -> "SplatCloud":
        """Splats whose label is in ``labels``."""
        return self.select(np.isin(self.labels, np.asarray(labels, dtype=np.int32)))


def concatenate(clouds: Sequence[SplatCloud]) -> SplatCloud:
    """One cloud holding all splats of ``clouds`` (labels kept); SH is zero-padded to the highest degree."""
    if not clouds:
        return SplatCloud.empty()
    degree = max(c.sh_degree for c in clouds)
    clouds = [c if c.sh_degree == degree else c.with_sh_degree(degree) for c in clouds]
    return SplatCloud(*(np.concatenate([getattr(c, f) for c in clouds]) for f in
                        ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh", "labels")))


# ---------------------------------------------------------------- pose math
def is_rigid(T: np.ndarray, atol: float = 1e-5) -> bool:
    """Whether T [4, 4] is a rigid transform: orthonormal rotation with det +1, last row [0, 0, 0, 1]."""
    T = np.asarray(T, dtype=np.float64)
    R = T[:3, :3]
    return bool(np.allclose(R @ R.T, np.eye(3), atol=atol) and np.linalg.det(R) > 0
                and np.allclose(T[3], [0, 0, 0, 1]))


def quat_multiply_wxyz(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of wxyz quaternions, broadcasting over leading axes. Returns float64."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def rotation_to_quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Unit wxyz quaternion [4] of a 3x3 rotation matrix (w >= 0)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat()
    q = np.array([w, x, y, z])
    return q if w >= 0 else -q


def quat_wxyz_to_rotation(q: np.ndarray) -> np.ndarray:
    """Rotation matrices [..., 3, 3] of (not necessarily unit) wxyz quaternions [..., 4]."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


"""UR5 kinematics from UR's published DH table: forward kinematics, the analytic inverse (all 8 branches),
and poses <-> ur-rtde's [x, y, z, rx, ry, rz].

DH (standard convention, T_{i-1,i} = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)); ``fk`` gives T_base_flange, the
tool flange in the controller's base frame, which is what a UR controller reports as the TCP pose when the
TCP offset is zero. ``ik`` solves T_base_flange for q in closed form: shoulder pan from the wrist centre
(2 branches: shoulder left/right), wrist 2 from the flange position (2: wrist up/down), wrist 3 from the
orientation, then elbow, shoulder lift and wrist 1 as a planar 2-link problem (2: elbow up/down). At a
wrist singularity (sin q5 = 0) q6 is free and taken from ``q6_free``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

D = np.array([0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823])  # m
A = np.array([0.0, -0.425, -0.39225, 0.0, 0.0, 0.0])  # m
ALPHA = np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])  # rad
LINK_MASSES = np.array([3.7, 8.393, 2.275, 1.219, 1.219, 0.1879])  # kg
JOINT_LIMIT = 2 * np.pi  # rad: every UR5 joint turns within [-2 pi, 2 pi]
MAX_ROTATION = 2 * np.pi  # rad: the longest rotation vector taken (a UR reports angles in [0, pi])


def dh_transform(q: float, d: float, a: float, alpha: float) -> np.ndarray:
    """[4, 4] Rz(q) Tz(d) Tx(a) Rx(alpha)."""
    cq, sq, ca, sa = np.cos(q), np.sin(q), np.cos(alpha), np.sin(alpha)
    return np.array([[cq, -sq * ca, sq * sa, a * cq],
                     [sq, cq * ca, -cq * sa, a * sq],
                     [0.0, sa, ca, d],
                     [0.0, 0.0, 0.0, 1.0]])


def fk_frames(q) -> list[np.ndarray]:
    """[T_base_1, T_base_2, ..., T_base_6]: each joint's DH frame in the base frame, for joints q [6] (rad)."""
    T, frames = np.eye(4), []
    for i in range(6):
        T = T @ dh_transform(q[i], D[i], A[i], ALPHA[i])
        frames.append(T)
    return frames


def fk(q, tcp: np.ndarray | None = None) -> np.ndarray:
    """T_base_tcp [4, 4] for joints q [6] (rad); ``tcp``: T_flange_tcp (default identity)."""
    T = fk_frames(q)[-1]
    return T if tcp is None else T @ tcp


def _wrap(angle):
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def ik(T_base_flange: np.ndarray, q6_free: float = 0.0) -> np.ndarray:
    """All joint solutions [M, 6] (rad, each in [-pi, pi), M <= 8) with fk(q) == T_base_flange; empty
    [0, 6] when the pose is out of reach."""
    T = np.asarray(T_base_flange, dtype=np.float64)
    d4, d6 = D[3], D[5]
    a2, a3 = A[1], A[2]
    p05 = T[:3, 3] - d6 * T[:3, 2]  # wrist centre (origin of frame 5)
    r = np.hypot(p05[0], p05[1])
    if r < d4 - 1e-12:
        return np.zeros((0, 6))
    phi = np.arccos(np.clip(d4 / r, -1.0, 1.0))
    psi = np.arctan2(p05[1], p05[0])
    solutions = []
    for q1 in (psi + phi + np.pi / 2, psi - phi + np.pi / 2):
        s1, c1 = np.sin(q1), np.cos(q1)
        c5 = (T[0, 3] * s1 - T[1, 3] * c1 - d4) / d6
        if abs(c5) > 1 + 1e-9:
            continue
        for q5 in (np.arccos(np.clip(c5, -1, 1)), -np.arccos(np.clip(c5, -1, 1))):
            s5 = np.sin(q5)
            T60 = np.linalg.inv(T)
            if abs(s5) < 1e-9:
                q6 = q6_free
            else:
                q6 = np.arctan2((-T60[1, 0] * s1 + T60[1, 1] * c1) / s5, (T60[0, 0] * s1 - T60[0, 1] * c1) / s5)
            T01 = dh_transform(q1, D[0], A[0], ALPHA[0])
            T45 = dh_transform(q5, D[4], A[4], ALPHA[4])
            T56 = dh_transform(q6, D[5], A[5], ALPHA[5])
            T14 = np.linalg.inv(T01) @ T @ np.linalg.inv(T45 @ T56)
            p13 = T14[:3, 3] - d4 * T14[:3, 1]  # origin of frame 3 in frame 1
            dist2 = p13[0] ** 2 + p13[1] ** 2
            c3 = (dist2 - a2 ** 2 - a3 ** 2) / (2 * a2 * a3)
            if abs(c3) > 1 + 1e-9:
                continue
            for q3 in (np.arccos(np.clip(c3, -1, 1)), -np.arccos(np.clip(c3, -1, 1))):
                q2 = np.arctan2(p13[1], p13[0]) - np.arctan2(a3 * np.sin(q3), a2 + a3 * np.cos(q3))
                T13 = dh_transform(q2, D[1], A[1], ALPHA[1]) @ dh_transform(q3, D[2], A[2], ALPHA[2])
                T34 = np.linalg.inv(T13) @ T14
                q4 = np.arctan2(T34[1, 0], T34[0, 0])
                solutions.append(_wrap([q1, q2, q3, q4, q5, q6]))
    return np.array(solutions).reshape(-1, 6)


def nearest_ik(T_base_flange: np.ndarray, q_now, limit: float = JOINT_LIMIT) -> np.ndarray | None:
    """The solution nearest (max joint move) to ``q_now`` [6] (rad), each joint shifted by whole turns where that
    brings it closer while keeping |q| <= ``limit`` (rad, at least pi; also when ``q_now`` lies beyond it); None when
    the pose is out of reach."""
    q_now = np.asarray(q_now, dtype=np.float64)
    best, best_cost = None, np.inf
    for q in ik(T_base_flange, q6_free=float(q_now[5])):
        turns = np.clip(np.round((q_now - q) / (2 * np.pi)), np.ceil((-limit - q) / (2 * np.pi)),
                        np.floor((limit - q) / (2 * np.pi)))
        q = q + 2 * np.pi * turns
        cost = np.abs(q - q_now).max()
        if cost < best_cost:
            best, best_cost = q, cost
    return best


def joints_problem(q, limit: float = JOINT_LIMIT) -> str | None:
    """Why ``q`` is not a joint target (6 finite angles, rad, each within +-``limit`` rad), or None when it is."""
    q = np.asarray(q, dtype=np.float64)
    if q.shape != (6,) or not np.isfinite(q).all():
        return f"a joint target is 6 finite angles (rad), got {q.tolist()}"
    beyond = [f"joint {i} = {v:.3f} rad" for i, v in enumerate(q) if abs(v) > limit]
    if beyond:
        return f"{', '.join(beyond)} beyond the joint limit +-{limit:.3f} rad"
    return None


def rtde_pose_problem(pose) -> str | None:
    """Why ``pose`` is not a ur-rtde pose [x, y, z, rx, ry, rz] (m, rotation vector in rad): not 6 numbers, one
    not finite, a rotation vector longer than ``MAX_ROTATION`` (1e300 rad is no rotation in floating point);
    None when it is one."""
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (6,):
        return f"a pose is [x, y, z, rx, ry, rz], got shape {pose.shape}"
    if not np.isfinite(pose).all():
        return "it holds a NaN or infinite number"
    angle = math.hypot(*pose[3:])  # rad; no overflow for 1e300
    if angle > MAX_ROTATION:
        return f"its rotation vector is {angle:.3g} rad long (at most {MAX_ROTATION:.3f})"
    return None


def rtde_pose_to_matrix(pose) -> np.ndarray:
    """ur-rtde pose [x, y, z, rx, ry, rz] (m, rotation vector in rad) -> [4, 4]."""
    pose = np.asarray(pose, dtype=np.float64)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(pose[3:]).as_matrix()
    T[:3, 3] = pose[:3]
    return T


def matrix_to_rtde_pose(T: np.ndarray) -> np.ndarray:
    """[4, 4] -> ur-rtde pose [x, y, z, rx, ry, rz]; the rotation vector's angle lies in [0, pi] as the
    controller reports it."""
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec()])

"""UR5 kinematics: FK against an independent product-of-exponentials model built from the joint axes, UR's
zero pose, IK branches that all reproduce the pose, the nearest branch, and ur-rtde pose vectors."""

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from robot_bridge.kinematics import A, D, fk, ik, matrix_to_rtde_pose, nearest_ik, rtde_pose_to_matrix


def poe(q) -> np.ndarray:
    """T_base_flange by the product of exponentials: each joint a screw (axis w through point p) at q = 0."""
    d1, d4, d5, d6, a2, a3 = D[0], D[3], D[4], D[5], A[1], A[2]
    axes = [((0, 0, 1), (0, 0, 0)), ((0, -1, 0), (0, 0, d1)), ((0, -1, 0), (a2, 0, d1)),
            ((0, -1, 0), (a2 + a3, 0, d1)), ((0, 0, -1), (a2 + a3, -d4, 0)), ((0, -1, 0), (a2 + a3, 0, d1 - d5))]
    home = np.eye(4)
    home[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # flange axes at q = 0: x = x0, y = z0, z = -y0
    home[:3, 3] = [a2 + a3, -(d4 + d6), d1 - d5]
    T = np.eye(4)
    for (w, p), angle in zip(axes, q):
        w, p = np.array(w, float), np.array(p, float)
        twist = np.zeros((4, 4))
        twist[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
        twist[:3, 3] = -np.cross(w, p)
        T = T @ expm(twist * angle)
    return T @ home


def test_forward_kinematics_matches_the_screw_model_and_urs_zero_pose():
    np.testing.assert_allclose(fk(np.zeros(6))[:3, 3], [-0.81725, -0.19145, -0.005491], atol=1e-6)
    rng = np.random.default_rng(0)
    for q in rng.uniform(-2 * np.pi, 2 * np.pi, (50, 6)):
        np.testing.assert_allclose(fk(q), poe(q), atol=1e-9)


def test_every_ik_branch_reproduces_the_pose_and_one_is_the_start():
    rng = np.random.default_rng(1)
    eight = 0
    for q in rng.uniform(-np.pi, np.pi, (300, 6)):
        T = fk(q)
        solutions = ik(T, q6_free=q[5])
        assert 1 <= len(solutions) <= 8
        eight += len(solutions) == 8
        for s in solutions:
            np.testing.assert_allclose(fk(s), T, atol=1e-9)
        assert len({tuple(np.round(s, 6)) for s in solutions}) == len(solutions)
        gap = np.abs((solutions - q + np.pi) % (2 * np.pi) - np.pi).max(axis=1)
        assert gap.min() < 1e-7
    assert eight > 200  # most random poses have all 8 branches


def test_nearest_branch_and_out_of_reach():
    q_now = np.array([0.3, -1.2, 1.5, -1.9, -1.57, 0.4])
    target = fk(q_now + 0.05)
    q = nearest_ik(target, q_now)
    np.testing.assert_allclose(q, q_now + 0.05, atol=1e-8)
    wound = q_now.copy()
    wound[5] -= 2 * np.pi  # a wrist turned once round (within the +-2 pi limits): the nearest solution keeps it
    np.testing.assert_allclose(nearest_ik(fk(wound), wound), wound, atol=1e-8)
    far = np.eye(4)
    far[:3, 3] = [1.2, 0.0, 0.3]
    assert len(ik(far)) == 0 and nearest_ik(far, q_now) is None


def test_pose_vectors_round_trip_like_ur_rtde():
    rng = np.random.default_rng(2)
    for _ in range(100):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        T[:3, 3] = rng.uniform(-1, 1, 3)
        pose = matrix_to_rtde_pose(T)
        assert np.linalg.norm(pose[3:]) <= np.pi + 1e-12
        np.testing.assert_allclose(rtde_pose_to_matrix(pose), T, atol=1e-12)
    # a tool pointing straight down (the usual grasp pose): rotation of pi about x
    np.testing.assert_allclose(rtde_pose_to_matrix([0.1, -0.4, 0.3, np.pi, 0, 0])[:3, 2], [0, 0, -1], atol=1e-12)
    assert matrix_to_rtde_pose(np.eye(4)) == pytest.approx(np.zeros(6))

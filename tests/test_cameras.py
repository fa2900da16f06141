"""Camera key poses and trajectories."""

import numpy as np
from scipy.spatial.transform import Rotation

from pegasus_gen.geometry.cameras import interpolate_poses, look_at, orbit_key_poses


def centre(T):
    return -T[:3, :3].T @ T[:3, 3]


def test_key_poses_look_at_the_target_from_the_asked_range():
    rng = np.random.default_rng(0)
    target = np.array([0.1, -0.2, 0.05])
    for T in orbit_key_poses(target, rng, 50, distance=(0.5, 0.9), elevation_deg=(25, 60), jitter=0.0):
        c = centre(T)
        d = np.linalg.norm(c - target)
        el = np.degrees(np.arcsin((c - target)[2] / d))
        assert 0.5 <= d <= 0.9 and 25 <= el <= 60
        p = T[:3, :3] @ target + T[:3, 3]  # the target is straight ahead in the camera
        assert np.allclose(p[:2], 0, atol=1e-9) and p[2] > 0
        assert np.allclose(np.linalg.det(T[:3, :3]), 1)


def test_interpolation_hits_the_keys_and_moves_smoothly():
    rng = np.random.default_rng(1)
    keys = orbit_key_poses(np.zeros(3), rng, 4)
    frames = interpolate_poses(keys, 31)
    assert len(frames) == 31
    for k, i in zip(keys, [0, 10, 20, 30]):
        assert np.allclose(frames[i], k, atol=1e-9)
    steps_t = [np.linalg.norm(centre(a) - centre(b)) for a, b in zip(frames, frames[1:])]
    steps_r = [np.linalg.norm((Rotation.from_matrix(a[:3, :3] @ b[:3, :3].T)).as_rotvec())
               for a, b in zip(frames, frames[1:])]
    assert max(steps_t) < 0.15 and max(steps_r) < np.radians(25)
    for T in frames:  # every frame a proper rigid transform
        assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)


def test_slerp_halfway_between_two_views():
    a = look_at([1, 0, 0.5], [0, 0, 0])
    b = look_at([0, 1, 0.5], [0, 0, 0])
    mid = interpolate_poses([a, b], 3)[1]
    assert np.allclose(centre(mid), [0.5, 0.5, 0.5])
    angle_a = np.linalg.norm(Rotation.from_matrix(mid[:3, :3] @ a[:3, :3].T).as_rotvec())
    angle_b = np.linalg.norm(Rotation.from_matrix(mid[:3, :3] @ b[:3, :3].T).as_rotvec())
    assert np.isclose(angle_a, angle_b)


def test_intrinsics_from_fov_or_focal_lengths():
    from pegasus_gen.geometry.cameras import intrinsics

    K = intrinsics(640, 480, 90.0)
    assert np.isclose(K[0, 0], 320) and K[0, 0] == K[1, 1] and np.allclose(K[:2, 2], [319.5, 239.5])
    K = intrinsics(640, 480, 90.0, fx=500.0, cx=300.0)
    assert K[0, 0] == K[1, 1] == 500 and K[0, 2] == 300 and K[1, 2] == 239.5
    assert intrinsics(640, 480, 90.0, fx=500.0, fy=510.0)[1, 1] == 510

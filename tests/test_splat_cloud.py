"""SplatCloud: placement by absolute poses with exact SH rotation, composition and filters."""

import numpy as np
import pytest
from conftest import random_cloud
from scipy.spatial.transform import Rotation

from pegasus_gen.splats import sh as shlib
from pegasus_gen.splats.cloud import SplatCloud, concatenate, quat_wxyz_to_rotation


def random_pose(seed):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    T[:3, 3] = np.random.default_rng(seed).uniform(-1, 1, 3)
    return T


def unit_dirs(rng, n):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def covariances(cloud):
    M = quat_wxyz_to_rotation(cloud.quats_wxyz) * cloud.scales[:, None, :]
    return M @ M.transpose(0, 2, 1)


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_sh_rotation_matches_rotated_directions(degree):
    rng = np.random.default_rng(degree)
    coeffs = rng.normal(size=(50, shlib.num_coeffs(degree), 3))
    for seed in range(5):
        R = Rotation.random(random_state=seed).as_matrix()
        d = unit_dirs(rng, 50)
        np.testing.assert_allclose(shlib.evaluate(shlib.rotate(coeffs, R), d), shlib.evaluate(coeffs, d @ R),
                                   atol=1e-5)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_transformed_places_means_orientations_scales_and_colour(degree):
    rng = np.random.default_rng(10 + degree)
    cloud = random_cloud(rng, 100, sh_degree=degree)
    before = {f: getattr(cloud, f).copy() for f in ("means", "quats_wxyz", "sh")}
    T, s = random_pose(degree), 1.7
    R, t = T[:3, :3], T[:3, 3]
    placed = cloud.transformed(T, scale=s)
    np.testing.assert_allclose(placed.means, s * cloud.means @ R.T + t, atol=1e-5)
    np.testing.assert_allclose(quat_wxyz_to_rotation(placed.quats_wxyz),
                               R @ quat_wxyz_to_rotation(cloud.quats_wxyz), atol=1e-5)
    np.testing.assert_allclose(placed.log_scales, cloud.log_scales + np.log(s), atol=1e-5)
    np.testing.assert_allclose(covariances(placed), s * s * R @ covariances(cloud) @ R.T, atol=1e-6)
    assert np.array_equal(placed.opacity_logits, cloud.opacity_logits)
    assert np.array_equal(placed.labels, cloud.labels)
    d = unit_dirs(rng, 100)  # the colour seen along R d after placement is the colour seen along d before
    np.testing.assert_allclose(shlib.evaluate(placed.sh, d @ R.T), shlib.evaluate(cloud.sh, d), atol=1e-5)
    for f, value in before.items():  # the stored cloud is never modified
        assert np.array_equal(getattr(cloud, f), value)


def test_poses_compose_absolutely():
    cloud = random_cloud(np.random.default_rng(0), 80, sh_degree=3)
    T1, T2 = random_pose(1), random_pose(2)
    direct = cloud.transformed(T2)
    chained = cloud.transformed(T1).transformed(T2 @ np.linalg.inv(T1))
    np.testing.assert_allclose(chained.means, direct.means, atol=1e-5)
    np.testing.assert_allclose(covariances(chained), covariances(direct), atol=1e-6)
    np.testing.assert_allclose(chained.sh, direct.sh, atol=1e-5)


@pytest.mark.parametrize("bad", [np.diag([2.0, 2.0, 2.0, 1.0]), np.diag([1.0, 1.0, -1.0, 1.0]),
                                 np.full((4, 4), np.nan), np.eye(3)])
def test_non_rigid_transforms_are_refused(bad):
    with pytest.raises(ValueError):
        random_cloud(np.random.default_rng(0), 5).transformed(bad)


def test_bad_scale_is_refused():
    with pytest.raises(ValueError, match="scale"):
        random_cloud(np.random.default_rng(0), 5).transformed(np.eye(4), scale=0.0)


def test_shapes_are_validated():
    n = 4
    good = dict(means=np.zeros((n, 3)), quats_wxyz=np.zeros((n, 4)), log_scales=np.zeros((n, 3)),
                opacity_logits=np.zeros(n), sh=np.zeros((n, 4, 3)), labels=np.zeros(n, np.int32))
    SplatCloud(**good)
    for field, bad in [("means", np.zeros((n, 2))), ("quats_wxyz", np.zeros((n + 1, 4))),
                       ("sh", np.zeros((n, 5, 3))), ("labels", np.zeros(n - 1)), ("opacity_logits", np.zeros((n, 1)))]:
        with pytest.raises(ValueError):
            SplatCloud(**{**good, field: bad})


def test_concatenate_keeps_labels_and_pads_sh():
    rng = np.random.default_rng(0)
    a = random_cloud(rng, 30, sh_degree=0).with_label(0)
    b = random_cloud(rng, 20, sh_degree=3).with_label(5)
    both = concatenate([a, b])
    assert len(both) == 50 and both.sh_degree == 3
    assert np.array_equal(both.labels, np.r_[np.zeros(30), np.full(20, 5)])
    assert np.array_equal(both.sh[:30, 0], a.sh[:, 0]) and not both.sh[:30, 1:].any()
    assert np.array_equal(both.sh[30:], b.sh)
    assert np.array_equal(both.means, np.concatenate([a.means, b.means]))


def test_filters_select_exactly():
    rng = np.random.default_rng(1)
    cloud = random_cloud(rng, 500, labels=(0, 1, 2))
    lo, hi = np.array([-0.2, -0.3, -0.1]), np.array([0.3, 0.2, 0.4])
    inside = [i for i in range(len(cloud)) if all(lo[j] <= cloud.means[i, j] <= hi[j] for j in range(3))]
    assert np.array_equal(cloud.crop_box(lo, hi).means, cloud.means[inside])
    opaque = [i for i in range(len(cloud)) if 1 / (1 + np.exp(-float(cloud.opacity_logits[i]))) >= 0.5]
    assert np.array_equal(cloud.filter_opacity(0.5).means, cloud.means[opaque])
    assert set(cloud.filter_labels([0, 2]).labels) == {0, 2}
    assert len(cloud.filter_labels([0, 2])) == int(np.sum(cloud.labels != 1))


def test_sh_basis_is_orthonormal_and_in_the_3dgs_convention():
    m = 20000
    i = np.arange(m) + 0.5
    z = 1 - 2 * i / m
    phi = np.pi * (1 + 5**0.5) * i
    d = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], 1)
    B = shlib.basis(d, 3)
    np.testing.assert_allclose(4 * np.pi / m * B.T @ B, np.eye(16), atol=5e-3)
    c1 = 0.4886025119029199
    np.testing.assert_allclose(B[:, 1:4], np.stack([-c1 * d[:, 1], c1 * d[:, 2], -c1 * d[:, 0]], 1), atol=1e-12)
    np.testing.assert_allclose(B[:, 10], 2.890611442640554 * d[:, 0] * d[:, 1] * d[:, 2], atol=1e-12)

"""Ray-cast mesh depth against closed-form geometry, and the view coverage used to aim cameras."""

import numpy as np
import trimesh

from pegasus_gen.geometry.cameras import intrinsics_from_fov, look_at
from pegasus_gen.render.raycast import MeshRaycaster


def test_depth_of_a_tilted_plane_is_exact():
    plane = trimesh.Trimesh([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], [[0, 1, 2], [0, 2, 3]])
    K = intrinsics_from_fov(64, 48, 60)
    T = look_at([0.3, -1.2, 0.9], [0.1, 0.2, 0.0])
    depth = MeshRaycaster(plane).depth(K, T, 64, 48)
    # closed form: the ray through pixel (u, v) with unit z in the camera meets z_world = 0 at depth d
    u, v = np.meshgrid(np.arange(64), np.arange(48))
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones(u.shape)], -1)
    R_wc = T[:3, :3].T
    eye = -R_wc @ T[:3, 3]
    d_world = d_cam @ R_wc.T
    expected = -eye[2] / d_world[..., 2]
    expected = np.where(expected > 0, expected, 0)
    np.testing.assert_allclose(depth, expected, rtol=1e-5, atol=1e-5)


def test_the_surface_hit_by_each_pixel_is_where_its_depth_says():
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    K = intrinsics_from_fov(64, 48, 60)
    T = look_at([0.4, -1.1, 0.7], [0.05, 0.0, 0.02])
    caster = MeshRaycaster(mesh)
    face, weights = caster.surface(K, T, 64, 48)
    depth = caster.depth(K, T, 64, 48)
    hit = face >= 0
    assert ((depth > 0) == hit).all() and 0.1 < hit.mean() < 0.9
    assert (weights[~hit] == 0).all() and (weights[hit] >= -1e-5).all()
    np.testing.assert_allclose(weights[hit].sum(-1), 1.0, atol=1e-5)
    # the face's vertices weighted so lie on the pixel's ray at its depth (the camera frame)
    points = np.einsum("nk,nkc->nc", weights[hit], mesh.vertices[mesh.faces[face[hit]]])
    cam = points @ T[:3, :3].T + T[:3, 3]
    v, u = np.nonzero(hit)
    np.testing.assert_allclose(cam[:, 2], depth[hit], rtol=1e-4)
    np.testing.assert_allclose(cam[:, 0] / cam[:, 2] * K[0, 0] + K[0, 2], u, atol=1e-3)
    np.testing.assert_allclose(cam[:, 1] / cam[:, 2] * K[1, 1] + K[1, 2], v, atol=1e-3)


def test_view_coverage_is_full_over_a_table_and_partial_towards_its_edge():
    table = trimesh.creation.box((1.2, 0.8, 0.02))
    raycaster = MeshRaycaster(table)
    K = intrinsics_from_fov(640, 480, 60)
    assert raycaster.view_coverage(K, look_at([0.0, -0.3, 0.5], [0, 0, 0]), 640, 480) == 1.0
    grazing = raycaster.view_coverage(K, look_at([0.0, -0.2, 0.15], [0, 0.6, 0.1]), 640, 480)
    assert 0.05 < grazing < 0.7  # the far edge of the table is in view


def test_occlusion_within_a_reach_agrees_with_the_nearest_hit():
    rng = np.random.default_rng(3)
    mesh = trimesh.util.concatenate([trimesh.creation.icosphere(subdivisions=3, radius=0.2),
                                     trimesh.creation.box((0.1, 0.3, 0.2)).apply_translation((0.35, 0, 0))])
    caster = MeshRaycaster(mesh)
    origins = rng.uniform(-0.4, 0.5, (4000, 3))
    directions = rng.normal(size=(4000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    t = caster.cast(origins, directions)
    for reach in (0.15, 0.3, np.inf):
        occluded = caster.occluded(origins, directions, reach)
        nearest = np.isfinite(t) & (t <= reach)
        assert 0.05 < nearest.mean() < 0.95  # both answers occur: the comparison can fail
        # rays that graze an edge may tell apart in the last float bit: none is further than that from its reach
        differ = occluded != nearest
        assert differ.sum() <= 2 and np.all(np.abs(t[differ] - reach) < 1e-5)
    assert caster.occluded(origins[:5, None, :], directions[None, :7]).shape == (5, 7)  # broadcast as cast

"""Contact shadows: which splats darken, by how much, and that the darkening is a plain scale of the colour."""

import numpy as np
import pytest
import trimesh
from conftest import random_cloud

from pegasus_gen.dataset.config import ShadowConfig, load_config
from pegasus_gen.dataset.scene import shadowed_scene
from pegasus_gen.geometry.cameras import intrinsics_from_fov, look_at
from pegasus_gen.render.renderer import render
from pegasus_gen.render.shadows import (
    cone_directions,
    contact_shadows,
    darken,
    hemisphere_directions,
    occluder,
    occlusion,
)
from pegasus_gen.splats import procedural
from pegasus_gen.splats import sh as shlib


def shadow_params(**fields):
    return ShadowConfig(**fields).params()


def floor(rng, n=20_000):
    return procedural.plane(1.0, 1.0, n, lambda u, v: np.full((len(u), 3), 0.7), rng)


def box_at(centre, size=(0.1, 0.1, 0.1)):
    return trimesh.creation.box(extents=size).apply_translation(centre)


def colour(cloud, dirs):
    return shlib.evaluate(cloud.sh, dirs) + 0.5


def test_a_splat_under_an_object_darkens_and_one_far_away_is_unchanged(rng):
    env = floor(rng)
    box = box_at([0.0, 0.0, 0.06])  # 1 cm above the floor
    cube = random_cloud(rng, 500, center=(0, 0, 0.06), extent=0.05, labels=(1,))
    params = shadow_params(radius=0.1, strength=0.6)
    shaded, _ = contact_shadows(env, [cube], [box], params, np.random.default_rng(0))
    up = np.tile([0.0, 0.0, 1.0], (len(env), 1))
    before, after = colour(env, up).mean(1), colour(shaded, up).mean(1)
    r = np.linalg.norm(env.means[:, :2], axis=1)
    under, beside, far = r < 0.03, (r > 0.07) & (r < 0.09), r > 0.3
    assert (after[under] < 0.7 * before[under]).all()  # under the box the sky is nearly all hidden
    assert (after[beside] < before[beside] - 0.02).mean() > 0.9  # next to it, partly
    assert (after[beside] > after[under].max()).all()
    np.testing.assert_array_equal(shaded.sh[far], env.sh[far])  # out of reach: untouched
    unshaded, _ = contact_shadows(env, [cube], [box_at([0.0, 0.0, 0.6])], params, np.random.default_rng(0))
    np.testing.assert_array_equal(unshaded.sh, env.sh)  # the same object 55 cm up shades nothing


def test_objects_are_shaded_by_the_others_not_by_themselves(rng):
    env = floor(rng, 2000)
    a = random_cloud(rng, 300, center=(0, 0, 0.06), extent=0.04, labels=(1,), sh_degree=0)
    b = random_cloud(rng, 300, center=(0.5, 0.5, 0.06), extent=0.04, labels=(2,), sh_degree=0)
    meshes = [box_at([0, 0, 0.06]), box_at([0.5, 0.5, 0.06])]
    _, (alone_a, alone_b) = contact_shadows(env, [a, b], meshes, shadow_params(), np.random.default_rng(0))
    np.testing.assert_array_equal(alone_a.sh, a.sh)  # nothing else within reach of either
    np.testing.assert_array_equal(alone_b.sh, b.sh)
    roof = box_at([0, 0, 0.12], (0.3, 0.3, 0.02))  # a plate just over a (its splats reach z = 0.1)
    _, (under_roof, _) = contact_shadows(env, [a, b], [meshes[0], roof], shadow_params(), np.random.default_rng(0))
    up = np.tile([0.0, 0.0, 1.0], (len(a), 1))
    lit = (colour(a, up) > 0.05).all(1)
    assert (colour(under_roof, up)[lit] < colour(a, up)[lit] - 0.01).all(1).mean() > 0.9


def test_only_the_splats_in_reach_are_recomputed_and_they_match_the_whole_cloud_darkened(rng):
    env = floor(rng, 30_000)
    meshes = [box_at([-0.3, 0.2, 0.06]), box_at([0.25, -0.1, 0.08], (0.06, 0.2, 0.1))]
    objects = [random_cloud(rng, 200, center=m.bounding_box.centroid, extent=0.04, labels=(k + 1,))
               for k, m in enumerate(meshes)]
    params = shadow_params(radius=0.1, strength=0.6, light_direction=(0.3, 0.2, 1.0))
    shaded, _ = contact_shadows(env, objects, meshes, params, np.random.default_rng(3))
    # the reference: every splat's distance to each object's sphere (about its box's middle, holding its vertices)
    reach = np.zeros(len(env), bool)
    for m in meshes:
        centre = m.bounds.mean(axis=0)
        radius = np.linalg.norm(m.vertices - centre, axis=1).max()
        reach |= np.linalg.norm(env.means - centre, axis=1) < radius + params.radius
    assert 0 < reach.sum() < len(env) / 2
    factor = np.ones(len(env))
    factor[reach] = 1.0 - params.strength * occlusion(env.means[reach], meshes, params, np.random.default_rng(3))
    np.testing.assert_allclose(shaded.sh, darken(env, factor).sh, atol=1e-6)  # the whole cloud darkened at once
    np.testing.assert_array_equal(shaded.sh[~reach], env.sh[~reach])  # the rest bit for bit as it was


def test_darkening_scales_the_rendered_colour_in_every_direction(rng):
    cloud = random_cloud(rng, 200, sh_degree=3)
    factor = rng.uniform(0.2, 1.0, len(cloud))
    dirs = rng.normal(size=(len(cloud), 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    np.testing.assert_allclose(colour(darken(cloud, factor), dirs), factor[:, None] * colour(cloud, dirs),
                               atol=1e-5)


def test_sky_directions_are_cosine_weighted_and_the_cone_is_tight():
    d = hemisphere_directions(4096)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    assert (d[:, 2] >= 0).all()
    assert d[:, 2].mean() == pytest.approx(2 / 3, abs=0.01)  # E[cos theta] under cos-weighting
    assert np.abs(d[:, :2].mean(0)).max() < 0.01
    axis = np.array([1.0, 2.0, 3.0]) / np.sqrt(14)
    cone = cone_directions(axis, 10.0, 64)
    angles = np.degrees(np.arccos(np.clip(cone @ axis, -1, 1)))
    assert angles.max() <= 10.0 + 1e-6 and angles.min() < 2.0


def test_a_wall_over_half_the_sky_hides_half_of_it():
    points = np.random.default_rng(1).uniform([-0.05, -0.05, 0], [0.05, 0.05, 0], (400, 3))
    half_roof = trimesh.creation.box(extents=(100, 200, 0.01)).apply_translation([50.0, 0, 0.2])
    params = shadow_params(radius=2.0, rays=64)  # the plate 0.2 m up: all but 1 % of the half-sky hits within 2 m
    share = occlusion(points, [half_roof], params, np.random.default_rng(0))
    assert share.mean() == pytest.approx(0.5, abs=0.04)
    assert occlusion(points, [half_roof], shadow_params(radius=0.1), np.random.default_rng(0)).max() == 0.0


def test_the_key_light_is_blocked_only_from_its_side():
    point = np.zeros((1, 3))
    post = box_at([0.3, 0.0, 0.3], (0.05, 0.05, 0.05))  # up and to +x
    light_only = dict(radius=1e-3, light_weight=1.0, light_cone_deg=1.0)
    towards = shadow_params(**light_only, light_direction=(1.0, 0.0, 1.0))
    away = shadow_params(**light_only, light_direction=(-1.0, 0.0, 1.0))
    assert occlusion(point, [post], towards, np.random.default_rng(0))[0] == 1.0
    assert occlusion(point, [post], away, np.random.default_rng(0))[0] == 0.0


def test_a_shaded_scene_renders_darker_only_near_the_objects(rng):
    env, objects, poses = procedural.tabletop_scene(60_000, rng, sh_degree=1)
    placed = [o.transformed(T) for o, T in zip(objects, poses)]
    meshes = [trimesh.creation.box(bounds=[o.means.min(0), o.means.max(0)]).apply_transform(T)
              for o, T in zip(objects, poses)]
    shaded_env, shaded = contact_shadows(env, placed, meshes, shadow_params(), np.random.default_rng(0))
    K, T = intrinsics_from_fov(160, 120, 55), look_at([0.6, -0.4, 0.6], [0, 0, 0.05])
    plain = render([env, *placed], K, T, 160, 120, device="cpu")
    dark = render([shaded_env, *shaded], K, T, 160, 120, device="cpu")
    assert (dark.rgb <= plain.rgb + 1e-4).all()
    darker = (plain.rgb - dark.rgb).mean(-1) > 0.02
    assert 0.002 < darker.mean() < 0.3  # some pixels, not the whole image
    np.testing.assert_array_equal(dark.depth, plain.depth)  # geometry untouched


def test_a_fine_surface_shades_through_a_coarse_occluder_as_it_would_itself():
    """A fine model (a 20,480-triangle sphere resting on the floor) is clustered to a few thousand triangles for
    the shadows; the floor's occlusion under it stays within the shadows' own sampling noise (16 rays)."""
    fine = trimesh.creation.icosphere(subdivisions=5, radius=0.05).apply_translation([0, 0, 0.051])
    coarse = occluder(fine)
    assert len(coarse.faces) < len(fine.faces) / 2 and occluder(fine) is coarse  # made once
    small = box_at([0, 0, 0.05])
    assert occluder(small) is small
    u, v = np.meshgrid(np.linspace(-0.12, 0.12, 60), np.linspace(-0.12, 0.12, 60))
    points = np.column_stack([u.ravel(), v.ravel(), np.full(u.size, 0.001)])
    params = shadow_params()
    a = occlusion(points, [fine], params, np.random.default_rng(0))
    b = occlusion(points, [coarse], params, np.random.default_rng(0))
    assert a.max() > 0.5 and a.mean() > 0.1  # the sphere shades the floor under it
    # measured: mean |a - b| 0.0001 (one ray of 16 in 0.2 % of the points); a wrong occluder (the box of the
    # sphere's bounds) differs by 0.13 (mean occlusion 0.30 against 0.17)
    assert np.abs(a - b).mean() < 0.01 and abs(a.mean() - b.mean()) < 0.01


def test_a_share_of_the_scenes_is_shaded_each_by_its_own_draw():
    def shaded(*overrides):
        cfg = load_config(None, list(overrides))
        return np.array([shadowed_scene(cfg, i) for i in range(400)])

    half = shaded("shadows.share=0.5")
    assert 0.4 < half.mean() < 0.6  # binomial std 0.025 over 400 scenes
    assert np.array_equal(half, shaded("shadows.share=0.5"))  # the scene's own draw: the same every time
    assert 0.2 < np.mean(half != shaded("shadows.share=0.5", "seed=1")) < 0.8  # another seed, other scenes
    assert shaded().all() and not shaded("shadows.share=0").any()
    assert not shaded("shadows.enabled=false").any()

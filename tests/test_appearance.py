"""Appearance and sensor randomisation: exact colour transforms of splats, camera effects with the
properties of their physics, and randomised datasets that repeat from their seed and keep their labels."""

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest
import trimesh
from conftest import random_cloud
from scipy.spatial.transform import Rotation
from test_generate import config, dataset_files

from pegasus_gen.dataset.appearance import environment_texture, frame_effects, image_motion, object_colour_transforms
from pegasus_gen.dataset.config import AppearanceConfig
from pegasus_gen.dataset.validate import validate
from pegasus_gen.geometry.cameras import intrinsics_from_fov, look_at
from pegasus_gen.render.sensor import SensorEffects, apply_sensor, disc_kernel, streak_kernel
from pegasus_gen.splats import sh as shlib
from pegasus_gen.splats.cloud import SplatCloud
from pegasus_gen.splats.colour import (
    blend_colour,
    hue_rotation,
    shade_lambert,
    shade_specular,
    smooth_normals,
    splat_normals,
    transform_colour,
)
from pegasus_gen.splats.from_mesh import mesh_to_splats
from pegasus_gen.splats.procedural import random_texture


def colour(cloud, dirs):
    return shlib.evaluate(cloud.sh, dirs) + 0.5


def test_a_colour_transform_maps_the_colour_seen_from_every_direction(rng):
    cloud = random_cloud(rng, 300, sh_degree=3)
    dirs = rng.normal(size=(len(cloud), 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    M = rng.uniform(-0.5, 1.5, (3, 3))
    np.testing.assert_allclose(colour(transform_colour(cloud, M), dirs), colour(cloud, dirs) @ M.T, atol=1e-4)
    per_splat = rng.uniform(0, 1, (len(cloud), 3, 3))
    want = np.einsum("nij,nj->ni", per_splat, colour(cloud, dirs))
    np.testing.assert_allclose(colour(transform_colour(cloud, per_splat), dirs), want, atol=1e-4)


def test_a_blend_moves_the_colour_towards_the_texture_from_every_direction(rng):
    cloud = random_cloud(rng, 300, sh_degree=3)
    dirs = rng.normal(size=(len(cloud), 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    texture = random_texture(rng, (0.02, 0.1))(cloud.means)
    assert len(np.unique(texture, axis=0)) >= 2 and texture.min() >= 0 and texture.max() <= 1
    for weight in (0.0, 0.3, 1.0):
        np.testing.assert_allclose(colour(blend_colour(cloud, texture, weight), dirs),
                                   (1 - weight) * colour(cloud, dirs) + weight * texture, atol=1e-4)


def test_a_texture_in_the_objects_colours_takes_only_their_colours_and_leaves_the_default_draws_alone(rng):
    points = rng.uniform(-1, 1, (2000, 3))
    red, teal = np.array([0.8, 0.2, 0.1]), np.array([0.1, 0.6, 0.6])
    objects = []
    for c in (red, teal):  # clouds of one colour each
        cloud = random_cloud(rng, 200, sh_degree=0)
        objects.append(replace(cloud, sh=np.tile(shlib.rgb_to_sh_dc(c)[None, None], (200, 1, 1))))
    always = AppearanceConfig(retexture=1.0, texture_object_colours=1.0)
    for seed in range(8):
        texture, _ = environment_texture(always, np.random.default_rng(seed), objects)
        colours = np.unique(np.round(texture(points), 6), axis=0)
        assert all(np.allclose(c, red, atol=1e-6) or np.allclose(c, teal, atol=1e-6) for c in colours)
        texture, _ = environment_texture(AppearanceConfig(retexture=1.0), np.random.default_rng(seed), objects)
        assert not any(np.allclose(c, red, atol=1e-3) or np.allclose(c, teal, atol=1e-3)
                       for c in np.unique(np.round(texture(points), 6), axis=0))
    # off (the default) or not repainted: the same draws as without the objects, and the scene's stream as far on
    for cfg in (AppearanceConfig(retexture=1.0), AppearanceConfig(retexture=0.0, texture_object_colours=1.0)):
        a, b = np.random.default_rng(5), np.random.default_rng(5)
        with_objects, without = environment_texture(cfg, a, objects), environment_texture(cfg, b)
        assert (with_objects is None) == (without is None) and a.uniform() == b.uniform()
        if without is not None:
            np.testing.assert_array_equal(with_objects[0](points), without[0](points))


def test_lambert_shading_lights_the_side_facing_the_light_and_keeps_ambient_behind():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    sphere.visual.vertex_colors = np.tile([200, 120, 60, 255], (len(sphere.vertices), 1))
    cloud = mesh_to_splats(sphere, np.random.default_rng(0), spacing=0.004)
    centre = np.array([0.3, -0.2, 0.1])
    cloud = cloud.transformed(np.block([[np.eye(3), centre[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]]))
    outward = (cloud.means - centre) / np.linalg.norm(cloud.means - centre, axis=1, keepdims=True)
    assert np.mean(np.sum(splat_normals(cloud, centre) * outward, axis=1) > 0.95) > 0.95  # the sphere's normals
    light, ambient = np.array([0.0, 0.0, 2.0]), 0.4
    before, after = colour(cloud, outward), colour(shade_lambert(cloud, centre, light, ambient), outward)
    facing = np.maximum(outward[:, 2], 0)
    expected = before * (ambient + (1 - ambient) * 1.5 * facing)[:, None]
    error = np.abs(after - expected)  # splat normals are the sphere's to a few degrees
    assert np.median(error) < 0.01 and np.quantile(error, 0.99) < 0.06  # measured: 1e-4 and 0.034
    below = outward[:, 2] < -0.2
    np.testing.assert_allclose(after[below], ambient * before[below], atol=1e-4)  # away from the light: ambient
    ratio = after[below] / before[below]
    assert np.allclose(ratio, ratio[:, :1], atol=1e-4)  # a grey factor: the hue stays


def flat_patch(tilt_deg: float, count: int = 400):
    """Flat splats on the plane z = 0 (5 cm square), each tilted about a random horizontal axis by |N(0, tilt)|."""
    rng = np.random.default_rng(3)
    means = np.column_stack([rng.uniform(-0.025, 0.025, (count, 2)), np.zeros(count)])
    axes = np.column_stack([rng.normal(size=(count, 2)), np.zeros(count)])
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    x, y, z, w = Rotation.from_rotvec(axes * np.radians(np.abs(rng.normal(0, tilt_deg, (count, 1))))).as_quat().T
    return SplatCloud(means=means, quats_wxyz=np.column_stack([w, x, y, z]),
                      log_scales=np.log(np.tile([0.002, 0.002, 0.0001], (count, 1))),
                      opacity_logits=np.full(count, 3.0), sh=np.full((count, 1, 3), shlib.rgb_to_sh_dc(0.3)),
                      labels=np.zeros(count, np.int32))


def test_a_highlight_peaks_where_the_surface_mirrors_the_light_to_the_eye_and_is_the_same_on_every_channel():
    cloud = flat_patch(0.0)
    normals = np.tile([0.0, 0.0, 1.0], (len(cloud), 1))
    centre = np.array([0.0, 0.0, -0.1])  # below the patch: splat_normals point up
    np.testing.assert_allclose(splat_normals(cloud, centre), normals, atol=1e-9)
    strength, shininess = 0.5, 20.0
    up = np.array([0.0, 0.0, 1.0])
    for angle in (0.0, 10.0, 40.0):  # the light straight above, the eye `angle` degrees off it, far away
        a = np.radians(angle)
        eye = 1e4 * np.array([np.sin(a), 0.0, np.cos(a)])
        after = shlib.sh_dc_to_rgb(shade_specular(cloud, normals, up, eye, strength, shininess).sh[:, 0])
        # n . h = cos(angle / 2): h halves the angle between the light and the eye
        np.testing.assert_allclose(after - 0.3, strength * np.cos(a / 2) ** shininess, atol=1e-6)
    eye = np.array([0.0, 0.0, 10.0])
    below = shade_specular(cloud, normals, -up, eye, strength, shininess)  # lit from behind: no highlight
    np.testing.assert_allclose(shlib.sh_dc_to_rgb(below.sh[:, 0]), 0.3, atol=1e-9)
    at_origin = cloud.replace(means=np.zeros_like(cloud.means))
    opposite = shade_specular(at_origin, normals, up, -eye, strength, shininess)  # the eye exactly opposite the light
    np.testing.assert_allclose(shlib.sh_dc_to_rgb(opposite.sh[:, 0]), 0.3, atol=1e-9)


def test_smoothed_normals_take_a_bumpy_surface_flat_and_keep_a_sphere_round():
    bumpy = flat_patch(15.0)
    centre = np.array([0.0, 0.0, -0.1])
    raw, smooth = splat_normals(bumpy, centre), smooth_normals(bumpy, centre)
    np.testing.assert_allclose(np.linalg.norm(smooth, axis=1), 1.0, atol=1e-9)
    raw_tilt, smooth_tilt = (np.degrees(np.arccos(np.clip(n[:, 2], -1, 1))) for n in (raw, smooth))
    assert np.median(smooth_tilt) < np.median(raw_tilt) / 3  # measured: 1.6 against 11.0 degrees
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    sphere.visual.vertex_colors = np.tile([200, 120, 60, 255], (len(sphere.vertices), 1))
    cloud = mesh_to_splats(sphere, np.random.default_rng(0), spacing=0.004)
    outward = cloud.means / np.linalg.norm(cloud.means, axis=1, keepdims=True)
    assert np.quantile(np.sum(smooth_normals(cloud, np.zeros(3)) * outward, axis=1), 0.05) > 0.98  # measured 0.998


def test_smoothed_normals_turn_with_the_object(rng):
    # generation computes them once per asset in its own frame and turns them with its pose
    cloud = random_cloud(rng, 400)
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=1).as_matrix()
    T[:3, 3] = [0.4, -1.2, 0.3]
    want = smooth_normals(cloud, np.zeros(3)) @ T[:3, :3].T
    np.testing.assert_allclose(smooth_normals(cloud.transformed(T), T[:3, 3]), want, atol=1e-6)


def test_a_hue_turn_keeps_grey_and_brightness_and_turns_the_hue():
    for degrees in (-20.0, 7.0, 90.0):
        R = hue_rotation(degrees)
        np.testing.assert_allclose(R @ np.full(3, 0.4), np.full(3, 0.4), atol=1e-12)
        colours = np.random.default_rng(0).uniform(0, 1, (50, 3))
        np.testing.assert_allclose((colours @ R.T).mean(1), colours.mean(1), atol=1e-12)
        red = np.array([[[0.7, 0.35, 0.35]]], np.float32)  # unsaturated: no channel leaves 0..1
        turned = np.clip(red[0] @ R.T, 0, 1)[None].astype(np.float32)
        hue = cv2.cvtColor(turned, cv2.COLOR_RGB2HSV)[0, 0, 0]  # OpenCV float hue: degrees
        assert (hue - degrees) % 360 == pytest.approx(0, abs=2) or (degrees - hue) % 360 == pytest.approx(0, abs=2)
    np.testing.assert_allclose(hue_rotation(30) @ hue_rotation(50), hue_rotation(80), atol=1e-12)


@pytest.mark.parametrize("hue_deg", [8.0, 30.0])
def test_each_instance_turns_its_hue_on_its_own_across_the_range_and_no_further(hue_deg):
    cfg = AppearanceConfig(object_gain=(1.0, 1.0), object_hue_deg=hue_deg)
    transforms = object_colour_transforms(cfg, 400, np.random.default_rng(3))
    red = np.array([0.7, 0.35, 0.35], np.float32)  # hue 0, unsaturated: no turn leaves 0..1
    turned = np.stack([np.clip(M @ red, 0, 1) for M in transforms]).astype(np.float32)[None]
    hue = cv2.cvtColor(turned, cv2.COLOR_RGB2HSV)[0, :, 0]  # OpenCV float hue: degrees
    turns = (hue + 180) % 360 - 180
    assert np.abs(turns).max() <= hue_deg + 1  # within the range (OpenCV's hue of a clipped colour: < 1 degree off)
    assert turns.min() < 1 - 0.9 * hue_deg and turns.max() > 0.9 * hue_deg - 1  # both ways, near the ends
    assert abs(np.corrcoef(turns[:-1], turns[1:])[0, 1]) < 0.2  # one instance's turn says nothing of the next's


def test_a_camera_without_effects_changes_nothing():
    rgb = np.random.default_rng(0).uniform(0, 1, (40, 50, 3)).astype(np.float32)
    np.testing.assert_array_equal(apply_sensor(rgb, SensorEffects(), np.random.default_rng(0)), rgb)


def test_blur_kernels_keep_the_light_and_have_their_size():
    for radius in (0.7, 1.5, 3.2):
        k = disc_kernel(radius)
        assert k.sum() == pytest.approx(1.0, abs=1e-6)
        ys, xs = np.nonzero(k > 1e-6)
        c = k.shape[0] // 2
        assert np.hypot(xs - c, ys - c).max() <= radius + 1
    k = streak_kernel(8.0, 0.0)
    assert k.sum() == pytest.approx(1.0, abs=1e-6)
    rows = np.nonzero(k.sum(1) > 1e-6)[0]
    cols = np.nonzero(k.sum(0) > 1e-6)[0]
    assert len(rows) == 1 and 8 <= len(cols) <= 10  # a horizontal streak 8 px long


def test_motion_blur_smears_along_the_motion_only():
    image = np.zeros((60, 60, 3), np.float32)
    image[:, 30:] = 1.0  # a vertical edge
    image[30:, :, 1] = 1.0  # a horizontal edge (green)
    out = apply_sensor(image, SensorEffects(motion_px=(10.0, 0.0)), np.random.default_rng(0))
    assert 0.3 < out[10, 30, 0] < 0.7 and 0.3 < out[10, 29, 0] < 0.7  # across the vertical edge: smeared
    np.testing.assert_allclose(out[25:36, 10, 1], image[25:36, 10, 1], atol=1e-6)  # along the horizontal edge: not
    assert out[..., 0].mean() == pytest.approx(image[..., 0].mean(), abs=1e-3)


def test_noise_has_the_shot_and_read_variance():
    level = np.full((200, 200, 3), 0.25, np.float32)
    effects = SensorEffects(shot_noise=0.04, read_noise=0.01)
    out = apply_sensor(level, effects, np.random.default_rng(0))
    assert out.std() == pytest.approx(np.sqrt(0.04**2 * 0.25 + 0.01**2), rel=0.03)
    assert out.mean() == pytest.approx(0.25, abs=1e-3)
    np.testing.assert_array_equal(out, apply_sensor(level, effects, np.random.default_rng(0)))


def test_exposure_white_balance_and_gamma():
    grey = np.full((4, 4, 3), 0.25, np.float32)
    out = apply_sensor(grey, SensorEffects(exposure=2.0, white_balance=(1.2, 1.0, 0.8), gamma=2.0),
                       np.random.default_rng(0))
    np.testing.assert_allclose(out[0, 0], np.sqrt([0.6, 0.5, 0.4]), atol=1e-6)


def test_motion_blur_follows_the_image_motion_of_the_objects():
    K = intrinsics_from_fov(320, 240, 60)
    before, after = look_at([0.5, 0.0, 0.5], [0, 0, 0]), look_at([0.5, 0.1, 0.5], [0, 0, 0])
    motion = image_motion(K, before, after, np.zeros(3), frames_apart=2)
    assert np.linalg.norm(motion) == 0  # the look-at point stays at the image centre
    motion = image_motion(K, before, after, np.array([0.0, 0.1, 0.0]), frames_apart=2)
    assert np.linalg.norm(motion) > 1
    cfg = AppearanceConfig(enabled=True, shutter=(0.5, 0.5))
    effects, quality = frame_effects(cfg, np.random.default_rng(0), motion)
    np.testing.assert_allclose(effects.motion_px, motion * 0.5)
    assert cfg.jpg_quality[0] <= quality <= cfg.jpg_quality[1]


def test_a_randomised_dataset_repeats_from_its_seed_and_keeps_its_labels(library, tmp_path):
    options = ["scenes=2", "frames_per_scene=3", "appearance.enabled=true", "appearance.retexture=1",
               "shadows.enabled=true"]
    plain = generate_dataset(library, tmp_path / "plain", "scenes=2", "frames_per_scene=3")
    first = generate_dataset(library, tmp_path / "first", *options)
    again = generate_dataset(library, tmp_path / "again", *options, "workers=2")
    got, want = dataset_files(again), dataset_files(first)
    assert sorted(got) == sorted(want) and [k for k in want if got[k] != want[k]] == []
    report = validate(first)
    assert report.ok, report.problems[:3]
    for scene in ("000000", "000001"):  # the same objects, poses and cameras as without randomisation
        for name in ("scene_gt.json", "scene_camera.json"):
            assert json.loads((first / "train_pbr" / scene / name).read_text()) == \
                json.loads((plain / "train_pbr" / scene / name).read_text())
    a = cv2.imread(str(first / "train_pbr" / "000000" / "rgb" / "000000.jpg")).astype(float)
    b = cv2.imread(str(plain / "train_pbr" / "000000" / "rgb" / "000000.jpg")).astype(float)
    assert np.abs(a - b).mean() > 3  # and it looks different


def generate_dataset(library, out, *options):
    from pegasus_gen.dataset.generate import generate

    return generate(config(library, out, *options))


def frame_pair(a, b, im: int):
    """Frame ``im`` of scene 0 in datasets ``a`` and ``b`` ([H, W, 3] float each), the pixels of ``a``'s objects
    (visible masks) and those at least 7 px from them (past blur and JPEG bleed), [H, W] bool each."""
    scene = "train_pbr/000000"
    one, two = (cv2.imread(str(d / scene / "rgb" / f"{im:06d}.jpg")).astype(float) for d in (a, b))
    masks = [cv2.imread(str(p), 0) > 0 for p in sorted((a / scene / "mask_visib").glob(f"{im:06d}_*.png"))]
    objects = np.any(masks, axis=0)
    away = cv2.dilate(objects.astype(np.uint8), np.ones((15, 15), np.uint8)) == 0
    return one, two, objects, away


def test_a_light_on_the_objects_shades_only_the_objects_and_leaves_the_other_draws_alone(library, tmp_path):
    from pegasus_gen.dataset.scene import scene_looks

    options = ["scenes=1", "frames_per_scene=2", "appearance.enabled=true", "shadows.enabled=false"]
    cfg_dark, cfg_lit = (config(library, tmp_path / n, *options, f"appearance.object_light={v}")
                         for n, v in (("dark", 0), ("lit", 1)))
    dark, lit = scene_looks(cfg_dark, 0, 3, []), scene_looks(cfg_lit, 0, 3, [])
    assert dark.light is None and lit.light is not None and 0.35 <= lit.light[1] <= 0.75
    assert np.isclose(np.linalg.norm(lit.light[0]), 1) and lit.light[0][2] >= np.sin(np.radians(20)) - 1e-9
    assert np.array_equal(dark.environment, lit.environment)  # the light has its own stream
    assert all(np.array_equal(a, b) for a, b in zip(dark.objects, lit.objects))
    a, b = (generate_dataset(library, tmp_path / n, *options, f"appearance.object_light={v}")
            for n, v in (("plain", 0), ("shaded", 1)))
    for im in range(2):
        one, two, objects, away = frame_pair(a, b, im)
        diff = np.abs(one - two).mean(axis=2)
        assert diff[objects].mean() > 8 and diff[away].mean() < 1.5  # measured: 13.7-19.0 and 0.3-0.5


def test_highlights_brighten_only_the_lit_objects_and_change_no_other_draw(library, tmp_path):
    from pegasus_gen.dataset.scene import scene_looks

    options = ["scenes=1", "frames_per_scene=2", "appearance.enabled=true", "shadows.enabled=false",
               "appearance.object_light=1"]
    matte, glossy = (config(library, tmp_path / n, *options, f"appearance.object_specular=[{v}, {v}]")
                     for n, v in (("matte", 0), ("glossy", 0.8)))
    a, b = scene_looks(matte, 0, 3, []), scene_looks(glossy, 0, 3, [])
    assert a.light.specular == 0 and b.light.specular == 0.8 and 8 <= b.light.shininess <= 48
    assert np.array_equal(a.light.direction, b.light.direction) and a.light.ambient == b.light.ambient
    one, two = (generate_dataset(library, tmp_path / n, *options, f"appearance.object_specular=[{v}, {v}]")
                for n, v in (("plain", 0), ("shiny", 0.8)))
    for im in range(2):
        x, y, objects, away = frame_pair(one, two, im)
        brighter = (y - x).mean(axis=2)
        assert np.quantile(brighter[objects], 0.99) > 30 and brighter[objects].mean() > 3  # measured: 61-63, 9-11
        assert np.abs(brighter[away]).mean() < 1.5  # measured: 0.2-0.4

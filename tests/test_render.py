"""CPU renderer against the slow reference, and properties every correct renderer has."""

import logging

import numpy as np
import pytest
from conftest import random_cloud
from reference_renderer import reference_render
from scipy.spatial.transform import Rotation

from pegasus_gen.errors import PegasusError
from pegasus_gen.geometry.cameras import intrinsics_from_fov, look_at
from pegasus_gen.render.renderer import cuda_status, render
from pegasus_gen.splats import procedural as synthetic
from pegasus_gen.splats.cloud import SplatCloud, concatenate


def small_camera(width=40, height=30):
    K = np.array([[45.0, 0, 19.3], [0, 47.0, 14.6], [0, 0, 1]])  # fx != fy, off-centre principal point
    T = look_at([0.3, -1.8, 0.9], [0.0, 0.0, 0.0])
    return K, T, width, height


@pytest.mark.parametrize("seed,degree", [(0, 0), (1, 1), (2, 2), (3, 3), (4, 3)])
def test_cpu_matches_slow_reference(seed, degree):
    rng = np.random.default_rng(seed)
    cloud = random_cloud(rng, 60, sh_degree=degree, labels=(0, 3, 7))
    K, T, w, h = small_camera()
    bg = (0.2, 0.4, 0.6)
    out = render(cloud, K, T, w, h, background=bg, labels=(0, 3, 7, 99), device="cpu", alpha_min=0.0)
    ref = reference_render(cloud, K, T, w, h, background=bg)
    assert ref["alpha"].max() > 0.9 and (ref["alpha"] < 0.05).any()  # the scene covers part of the image
    np.testing.assert_allclose(out.rgb, np.clip(ref["rgb"], 0, 1), atol=2e-5)
    np.testing.assert_allclose(out.alpha, ref["alpha"], atol=2e-5)
    covered = ref["alpha"] > 1e-3
    # splats up to 27 cm across at 2 m: the renderer's affine camera model bends their depth on a pixel's ray
    # by up to 2.5 % (0.12-0.16 % median); surface-sized splats are held closer below
    depth_ratio = np.abs(out.depth[covered] / (ref["depth_sum"][covered] / ref["alpha"][covered]) - 1)
    assert depth_ratio.max() < 0.05 and np.median(depth_ratio) < 5e-3
    for i, label in enumerate((0, 3, 7)):
        np.testing.assert_allclose(out.label_weights[i], ref["weights"].get(label, 0), atol=2e-5)
    assert np.all(out.label_weights[3] == 0)  # label 99 is absent
    stacked = np.stack([ref["weights"].get(lab, np.zeros((h, w))) for lab in (0, 3, 7)])
    expected_label = np.where(stacked.sum(0) > 0, np.array([0, 3, 7])[stacked.argmax(0)], -1)
    clear = np.sort(stacked, axis=0)[-1] - np.sort(stacked, axis=0)[-2] > 1e-4  # no near-ties
    assert np.array_equal(out.label[clear], expected_label[clear])


def test_cpu_matches_reference_with_gaussians_outside_the_frustum():
    """Splats beside, behind and straddling the image edges (frustum clamp and culling paths)."""
    rng = np.random.default_rng(7)
    cloud = random_cloud(rng, 80, sh_degree=1, extent=1.6, scale_range=(0.02, 0.3))
    K, T, w, h = small_camera()
    out = render(cloud, K, T, w, h, device="cpu", alpha_min=0.0)
    ref = reference_render(cloud, K, T, w, h)
    np.testing.assert_allclose(out.rgb, np.clip(ref["rgb"], 0, 1), atol=2e-5)
    np.testing.assert_allclose(out.alpha, ref["alpha"], atol=2e-5)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_moving_object_and_camera_together_leaves_the_image_unchanged(seed):
    rng = np.random.default_rng(seed)
    obj = random_cloud(rng, 400, sh_degree=3, extent=0.15, scale_range=(0.005, 0.03), labels=(5,))
    T_world_obj = np.eye(4)
    T_world_obj[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    T_world_obj[:3, 3] = [0.1, -0.2, 0.3]
    K = intrinsics_from_fov(96, 72, 50)
    T_cam_world = look_at([0.8, -0.9, 0.9], [0.1, -0.2, 0.3])
    motion = np.eye(4)
    motion[:3, :3] = Rotation.random(random_state=100 + seed).as_matrix()
    motion[:3, 3] = rng.uniform(-2, 2, 3)
    a = render(obj.transformed(T_world_obj), K, T_cam_world, 96, 72, device="cpu")
    b = render(obj.transformed(motion @ T_world_obj), K, T_cam_world @ np.linalg.inv(motion), 96, 72,
               device="cpu")
    assert a.alpha.mean() > 0.05
    assert np.abs(a.rgb - b.rgb).mean() < 1 / 255
    assert np.abs(a.depth - b.depth).max() < 1e-4
    # and the view dependence is real: a different viewpoint of the same object changes colours
    c = render(obj.transformed(T_world_obj), K, look_at([-0.8, 0.9, 0.9], [0.1, -0.2, 0.3]), 96, 72, device="cpu")
    assert np.abs(a.rgb - c.rgb).mean() > 5 / 255


def dense_plane(rng, center, normal, size=1.2, n=40_000):
    """A dense opaque splat plane through ``center`` with unit ``normal``."""
    plane = synthetic.plane(size, size, n, lambda u, v: np.full((len(u), 3), 0.5), rng, sh_degree=0)
    R = Rotation.align_vectors([normal], [[0, 0, 1]])[0].as_matrix()
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = center
    return plane.transformed(T)


@pytest.mark.parametrize("seed", [0, 1])
def test_depth_of_surface_sized_splats_is_where_each_pixel_ray_meets_them(seed):
    # Millimetre splats (a scanned surface's) in random orientations: each splat's depth on a pixel is where
    # that pixel's ray meets its highest density, not its centre's z (1-3 mm off at the footprint's edge)
    rng = np.random.default_rng(seed)
    cloud = random_cloud(rng, 80, sh_degree=0, extent=0.05, scale_range=(0.0005, 0.004), opacity_range=(0.3, 0.9))
    K = np.array([[450.0, 0, 59.6], [0, 460.0, 44.3], [0, 0, 1]])
    T = look_at([0.1, -0.55, 0.3], [0.0, 0.0, 0.0])
    out = render(cloud, K, T, 120, 90, device="cpu", alpha_min=0.0)
    ref = reference_render(cloud, K, T, 120, 90)
    covered = ref["alpha"] > 1e-3
    error = np.abs(out.depth[covered] - ref["depth_sum"][covered] / ref["alpha"][covered])
    assert covered.sum() > 500 and error.max() < 1e-3 and np.median(error) < 1e-4, (error.max(), np.median(error))


def test_depth_of_a_fronto_parallel_plane_is_exact():
    rng = np.random.default_rng(0)
    cloud = dense_plane(rng, [0, 0, 2.0], [0, 0, -1.0])
    K = intrinsics_from_fov(64, 48, 30)
    out = render(cloud, K, np.eye(4), 64, 48, device="cpu")
    assert (out.alpha > 0.99).all()
    assert np.abs(out.depth - 2.0).max() < 1e-3


def test_depth_of_a_tilted_plane_follows_the_ray_intersection():
    rng = np.random.default_rng(1)
    normal = np.array([0.0, -np.sin(0.5), -np.cos(0.5)])  # tilted ~29 degrees about x, facing the camera
    center = np.array([0.0, 0.0, 1.5])
    cloud = dense_plane(rng, center, normal, size=1.6, n=200_000)
    w, h = 320, 240
    K = intrinsics_from_fov(w, h, 40)
    out = render(cloud, K, np.eye(4), w, h, device="cpu")
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], -1)
    z_true = (normal @ center) / (rays @ normal)  # z-depth where the ray meets the plane
    assert (out.alpha > 0.95).all()
    # Each splat's depth on a pixel is where the pixel's ray meets it: 0.14 mm at most off the plane here
    # (4 mm splats at 1.5 m); blending the splats' centre depths leaned 2 mm towards the camera.
    assert np.abs(out.depth - z_true).max() < 5e-4


def test_occluding_object_owns_the_label_and_depth():
    rng = np.random.default_rng(2)
    back = dense_plane(rng, [0, 0, 2.0], [0, 0, -1.0], n=20_000).with_label(0)
    front = dense_plane(rng, [0, 0, 1.0], [0, 0, -1.0], size=0.2, n=4_000).with_label(4)
    K = intrinsics_from_fov(64, 48, 30)
    out = render([back, front], K, np.eye(4), 64, 48, labels=(0, 4), device="cpu")
    centre = out.label[20:28, 28:36]
    assert (centre == 4).all() and np.abs(out.depth[20:28, 28:36] - 1.0).max() < 1e-3
    assert out.label[0, 0] == 0 and abs(out.depth[0, 0] - 2.0) < 1e-3
    np.testing.assert_allclose(out.label_weights.sum(0), out.alpha, atol=1e-5)
    assert np.array_equal(out.mask(4), out.label == 4)


def test_parts_render_like_their_concatenation():
    rng = np.random.default_rng(3)
    a = random_cloud(rng, 300, sh_degree=0, labels=(0,))
    b = random_cloud(rng, 300, sh_degree=3, labels=(1, 2))
    K, T, w, h = small_camera(80, 60)
    split = render([a, b], K, T, w, h, labels=(0, 1, 2), device="cpu")
    joined = render(concatenate([a, b]), K, T, w, h, labels=(0, 1, 2), device="cpu")
    np.testing.assert_allclose(split.rgb, joined.rgb, atol=1e-6)
    np.testing.assert_allclose(split.label_weights, joined.label_weights, atol=1e-6)
    assert np.array_equal(split.label, joined.label)


def test_empty_scene_is_background():
    K, T, w, h = small_camera()
    out = render(SplatCloud.empty(), K, T, w, h, background=(0.1, 0.2, 0.3), device="cpu")
    assert np.allclose(out.rgb, [0.1, 0.2, 0.3]) and (out.alpha == 0).all() and (out.depth == 0).all()
    assert (out.label == -1).all()


def test_rgb_is_clamped_not_wrapped():
    rng = np.random.default_rng(4)
    cloud = random_cloud(rng, 200, sh_degree=0)
    cloud = cloud.replace(sh=cloud.sh * 0 + 5.0)  # far brighter than 1
    K, T, w, h = small_camera()
    out = render(cloud, K, T, w, h, device="cpu")
    assert out.rgb.max() <= 1.0 and out.rgb.min() >= 0.0
    assert (out.rgb[out.alpha > 0.5] > 0.5).all()


def test_bad_camera_and_device_are_rejected():
    cloud = random_cloud(np.random.default_rng(0), 10)
    K, T, w, h = small_camera()
    with pytest.raises(ValueError, match="K must"):
        render(cloud, np.eye(2), T, w, h, device="cpu")
    with pytest.raises(ValueError, match="rigid"):
        render(cloud, K, T * 2, w, h, device="cpu")
    with pytest.raises(PegasusError, match="device"):
        render(cloud, K, T, w, h, device="tpu")


@pytest.mark.skipif(cuda_status()[0], reason="a CUDA GPU with gsplat is present")
def test_without_a_gpu_cuda_is_refused_and_auto_says_it_uses_cpu(caplog):
    cloud = random_cloud(np.random.default_rng(0), 10)
    K, T, w, h = small_camera()
    with pytest.raises(PegasusError, match="cuda.*not available"):
        render(cloud, K, T, w, h, device="cuda")
    from pegasus_gen.render import renderer as render_module

    render_module._log_auto_choice.cache_clear()
    with caplog.at_level(logging.INFO, logger="pegasus.render"):
        out = render(cloud, K, T, w, h, device="auto")
    assert out.backend == "cpu" and "using CPU" in caplog.text


def test_depth_sort_orders_front_to_back_like_a_stable_argsort():
    from pegasus_gen.render.cpu import sort_by_depth

    rng = np.random.default_rng(5)
    depth = rng.uniform(0.01, 50.0, 100_000)
    depth[::7] = 3.25  # ties keep index order
    keep = np.flatnonzero(rng.uniform(size=depth.size) < 0.8)
    expected = keep[np.argsort(depth[keep].astype(np.float32), kind="stable")]
    assert np.array_equal(sort_by_depth(depth, keep), expected)


@pytest.mark.parametrize("thin_px", [0.5, 1.5])
def test_antialiased_splats_keep_their_weight_where_classic_ones_grow(thin_px):
    # One Gaussian 1 m in front of a camera with fx = fy = 100 px, 1.5 px by thin_px in the image (a flat splat
    # seen edge-on when thin_px is small), opacity o. Over the pixels where alpha = o g(x) reaches the renderer's
    # threshold t = 1/255, alpha sums to 2 pi sqrt(det cov2d) (o - t). Classic adds EPS2D to cov2d; the
    # antialiased mode adds EPS2D_ANTIALIASED and scales o by sqrt(det cov2d / det(cov2d + EPS2D_ANTIALIASED I)),
    # which keeps the integral the undilated splat's (less the cut), while classic's grows (1.6x for the thin one).
    # (Thinner than 0.5 px, the sum over pixel centres departs from the integral by a few per cent: aliasing.)
    from pegasus_gen.render.cpu import ALPHA_THRESHOLD, EPS2D, EPS2D_ANTIALIASED

    o, sx, sy = 0.9, 1.5, thin_px
    cloud = SplatCloud(np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0, 0, 0]]),
                       np.log([[sx / 100, sy / 100, 1e-5]]), np.array([np.log(o / (1 - o))]), np.zeros((1, 1, 3)),
                       np.zeros(1, np.int32))
    K = np.array([[100.0, 0, 31.5], [0, 100.0, 31.5], [0, 0, 1]])
    root_det = sx * sy
    root_det_classic = np.sqrt((sx ** 2 + EPS2D) * (sy ** 2 + EPS2D))
    root_det_aa = np.sqrt((sx ** 2 + EPS2D_ANTIALIASED) * (sy ** 2 + EPS2D_ANTIALIASED))
    o_aa = o * root_det / root_det_aa
    classic = render(cloud, K, np.eye(4), 64, 64, device="cpu").alpha.sum()
    antialiased = render(cloud, K, np.eye(4), 64, 64, device="cpu", antialiased=True).alpha.sum()
    assert antialiased == pytest.approx(2 * np.pi * root_det_aa * (o_aa - ALPHA_THRESHOLD), rel=0.02)
    assert classic == pytest.approx(2 * np.pi * root_det_classic * (o - ALPHA_THRESHOLD), rel=0.02)
    assert classic > 1.1 * antialiased

"""Differentiable rasterizer (torch / gsplat) and 3DGS training (splat_training)."""

import math

import numpy as np
import pytest
import torch
from conftest import random_cloud

from pegasus_gen.geometry.cameras import intrinsics_from_fov, look_at
from pegasus_gen.render import differentiable as rasterizer_torch
from pegasus_gen.render.renderer import render
from pegasus_gen.scan.densify import densify_and_prune
from pegasus_gen.scan.splat_params import SplatParams
from pegasus_gen.scan.training import (
    SplatTrainConfig,
    TrainView,
    init_from_points,
    psnr,
    ssim,
    train_splats,
)
from pegasus_gen.splats import procedural as synthetic
from pegasus_gen.splats.cloud import SplatCloud


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """Small tensors: one intra-op thread is as fast here and does not stall when other processes share the
    CPU (two OpenMP threads waiting on each other made a 20 s training run take minutes on a loaded VM)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


FIELDS = ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh")


def tensors(cloud: SplatCloud, dtype=torch.float32, requires_grad=False, device="cpu"):
    return [torch.tensor(getattr(cloud, f), dtype=dtype, device=device).requires_grad_(requires_grad) for f in FIELDS]


# ----------------------------------------------------------------------------- rasterizer
@pytest.mark.parametrize("chunk", [1024, 37])  # 37: several chunks per tile, transmittance carried across them
@pytest.mark.parametrize("opacity_range", [(0.2, 0.99), (0.97, 0.995)])  # the second terminates pixels early
def test_torch_rasterizer_matches_numba_renderer(monkeypatch, chunk, opacity_range):
    monkeypatch.setattr(rasterizer_torch, "SPLAT_CHUNK", chunk)
    cloud = random_cloud(np.random.default_rng(0), 400, sh_degree=3, extent=0.3, opacity_range=opacity_range)
    w, h = 64, 48
    K = intrinsics_from_fov(w, h, 60)
    T = look_at([0.9, -0.6, 0.5], [0.0, 0.0, 0.0])
    bg = (0.2, 0.4, 0.6)
    ref = render(cloud, K, T, w, h, background=bg, device="cpu")
    out = rasterizer_torch.rasterize(*tensors(cloud), K, T, w, h, background=bg)
    assert out.rgb.shape == (h, w, 3) and out.alpha.shape == (h, w) and out.means2d.shape == (len(cloud), 2)
    assert 0.3 < ref.alpha.mean() and (ref.alpha > 0.999).mean() < 0.9  # covered, not trivially opaque
    # independent float32 / float64 implementations of the same math: agreement to float32 rounding
    assert np.abs(out.rgb.clamp(0, 1).numpy() - ref.rgb).max() < 2e-5
    assert np.abs(out.alpha.numpy() - ref.alpha).max() < 2e-5


def test_torch_rasterizer_sh_degree_limit_and_culling():
    rng = np.random.default_rng(1)
    cloud = random_cloud(rng, 200, sh_degree=3, extent=0.2)
    w, h = 32, 24
    K = intrinsics_from_fov(w, h, 60)
    T = look_at([0.8, 0.3, 0.4], [0.0, 0.0, 0.0])
    for degree in (0, 1, 2):
        ref = render(cloud.with_sh_degree(degree), K, T, w, h, device="cpu")
        out = rasterizer_torch.rasterize(*tensors(cloud), K, T, w, h, sh_degree=degree)
        assert np.abs(out.rgb.clamp(0, 1).numpy() - ref.rgb).max() < 2e-5
    # large splats centred beyond the widened frustum (x/z > 1.3 tan(fov/2)) that still reach into the image:
    # their EWA Jacobian is taken at the clamped direction, as in the numba renderer
    T_world_cam = np.linalg.inv(T)
    side = rng.uniform([0.8, -0.6, 0.9], [1.2, 0.6, 1.1], (20, 3)) * np.repeat([[1, 1, 1], [-1, 1, 1]], 10, axis=0)
    edge = random_cloud(rng, 20, scale_range=(0.2, 0.3), opacity_range=(0.5, 0.9))
    edge = edge.replace(means=side @ T_world_cam[:3, :3].T + T_world_cam[:3, 3])
    ref = render(edge, K, T, w, h, device="cpu")
    assert ref.alpha.mean() > 0.05
    out = rasterizer_torch.rasterize(*tensors(edge), K, T, w, h)
    assert np.abs(out.rgb.clamp(0, 1).numpy() - ref.rgb).max() < 2e-5
    assert np.abs(out.alpha.numpy() - ref.alpha).max() < 2e-5
    # a splat behind the camera and one far outside the view are culled: no effect, not visible
    culled = cloud.select(np.arange(2)).replace(
        means=(T_world_cam[:3, :3] @ np.array([[0.0, 0.0, -0.5], [5.0, 0.0, 1.0]]).T).T + T_world_cam[:3, 3])
    out = rasterizer_torch.rasterize(*tensors(culled), K, T, w, h)
    assert not out.visible.any() and float(out.alpha.max()) == 0.0


def _tiny_scene(rng, n=4):
    """n splats (SH degree 1) in front of a 10x8 camera, float64 leaves, low opacity (no early termination)."""
    means = rng.uniform(-0.15, 0.15, (n, 3))
    quats = rng.normal(size=(n, 4))
    log_scales = np.log(rng.uniform(0.05, 0.12, (n, 3)))
    logits = rng.uniform(-1.0, 1.0, n)
    sh = np.concatenate([rng.uniform(0, 1, (n, 1, 3)), rng.normal(0, 0.1, (n, 3, 3))], axis=1)
    leaves = [torch.tensor(a, dtype=torch.float64, requires_grad=True) for a in (means, quats, log_scales, logits, sh)]
    K = intrinsics_from_fov(10, 8, 60)
    T = look_at([1.2, -0.5, 0.4], [0.0, 0.0, 0.0])
    return leaves, K, T


def test_torch_rasterizer_gradients_match_finite_differences(monkeypatch):
    monkeypatch.setattr(rasterizer_torch, "SPLAT_CHUNK", 3)  # gradients also flow across chunks
    leaves, K, T = _tiny_scene(np.random.default_rng(3))

    weights = torch.rand(3, 8, 10, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(0))

    def f(*args):  # three random projections of all rgb and alpha values (few outputs: fast gradcheck)
        out = rasterizer_torch.rasterize_torch(*args, K, T, 10, 8, background=(0.3, 0.5, 0.7))
        return (weights * torch.cat([out.rgb, out.alpha[..., None]], dim=-1)).sum(dim=(1, 2, 3))

    assert rasterizer_torch.rasterize_torch(*leaves, K, T, 10, 8).visible.all()
    assert torch.autograd.gradcheck(f, tuple(leaves), eps=1e-6, atol=1e-6, rtol=1e-4)


def test_means2d_gradient_is_retained_and_correct():
    """d loss / d cx = sum of d loss / d mean2d.x (the principal point shifts every 2D mean)."""
    leaves, K, T = _tiny_scene(np.random.default_rng(4))
    target = torch.rand(8, 10, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))

    def loss_at(cx):
        K2 = K.copy()
        K2[0, 2] = cx
        out = rasterizer_torch.rasterize_torch(*leaves, K2, T, 10, 8)
        return ((out.rgb - target) ** 2).mean(), out

    loss, out = loss_at(K[0, 2])
    loss.backward()
    grad = out.means2d_grad()
    assert grad.shape == (4, 2) and grad.abs().sum() > 0
    eps = 1e-5
    with torch.no_grad():
        fd = (loss_at(K[0, 2] + eps)[0] - loss_at(K[0, 2] - eps)[0]) / (2 * eps)
    assert float(grad[:, 0].sum()) == pytest.approx(float(fd), rel=1e-5, abs=1e-10)


def test_ssim_and_psnr():
    g = torch.Generator().manual_seed(0)
    a = torch.rand(24, 32, 3, generator=g)
    assert float(ssim(a, a)) == pytest.approx(1.0, abs=1e-5)
    noise = torch.randn(a.shape, generator=g)
    scores = [float(ssim(a, (a + sigma * noise).clamp(0, 1))) for sigma in (0.05, 0.2, 0.5)]
    assert 1.0 > scores[0] > scores[1] > scores[2] and scores[2] < 0.6
    assert psnr(a, a) == math.inf
    assert psnr(np.zeros((4, 4)), np.full((4, 4), 0.1)) == pytest.approx(20.0)


# ------------------------------------------------------------------------- density control
def _params(n_small=5, n_large=5):
    """Splats 0..n_small-1 with std-dev 1 mm, the rest 5 cm; all opacity 0.5, random rotations."""
    rng = np.random.default_rng(0)
    n = n_small + n_large
    scales = np.where(np.arange(n)[:, None] < n_small, 0.001, 0.05) * np.ones((n, 3))
    cloud = SplatCloud(rng.uniform(-1, 1, (n, 3)), rng.normal(size=(n, 4)), np.log(scales), np.zeros(n),
                       rng.normal(size=(n, 16, 3)), np.zeros(n, np.int32))
    lrs = dict.fromkeys(("means", "quats_wxyz", "log_scales", "opacity_logits", "sh_dc", "sh_rest"), 1e-3)
    return cloud, SplatParams(cloud, lrs)


def test_densify_clones_small_splits_large_and_prunes_transparent():
    _, params = _params()
    # one optimiser step so the moments are non-zero: they must follow their splats
    sum(p.sum() for p in params.params.values()).backward()
    params.optimizer.step()
    moments_before = params.optimizer.state[params["opacity_logits"]]["exp_avg"].clone()
    means_before = params["means"].detach().numpy().copy()
    scales_before = np.exp(params["log_scales"].detach().numpy())
    with torch.no_grad():
        params["opacity_logits"][9] = -10.0  # transparent: pruned
    grad2d = torch.tensor([1e-3, 1e-3, 0, 0, 0, 1e-3, 1e-3, 0, 0, 0])  # 0, 1 small; 5, 6 large
    counts = densify_and_prune(params, grad2d, grad_threshold=2e-4, split_scale=0.01, min_opacity=0.005,
                               generator=torch.Generator().manual_seed(0))
    assert counts == {"cloned": 2, "split": 2, "pruned": 1, "before": 10, "after": 10 + 2 + 4 - 2 - 1}
    assert len(params) == 13
    means = params["means"].detach().numpy()
    scales = np.exp(params["log_scales"].detach().numpy())
    # survivors keep their order and rows: 0..4, 7, 8, then clones of 0, 1, then 2 children each of 5, 6
    kept = [0, 1, 2, 3, 4, 7, 8]
    np.testing.assert_allclose(means[:7], means_before[kept])
    np.testing.assert_allclose(means[7:9], means_before[[0, 1]])
    np.testing.assert_allclose(scales[9:], scales_before[[5, 6, 5, 6]] / 1.6, rtol=1e-5)
    children = means[9:]
    parents = means_before[[5, 6, 5, 6]]
    assert np.all(np.linalg.norm(children - parents, axis=1) < 0.05 * 5)  # drawn from the parent Gaussian
    assert np.all(np.linalg.norm(children - parents, axis=1) > 0)
    moments = params.optimizer.state[params["opacity_logits"]]["exp_avg"]
    assert moments.shape == (13,)
    np.testing.assert_allclose(moments[:7].numpy(), moments_before[kept].numpy())
    assert moments[7:].abs().sum() == 0  # new splats start with fresh moments
    assert params.optimizer.param_groups[0]["params"][0] is params["means"]


def test_densify_budget_and_large_prune():
    _, params = _params()
    grad2d = torch.tensor([5e-4, 9e-4, 3e-4, 0, 0, 0, 0, 0, 0, 0])
    counts = densify_and_prune(params, grad2d, grad_threshold=2e-4, split_scale=0.01, min_opacity=0.005,
                               max_splats=11)
    assert counts["cloned"] == 1 and len(params) == 11  # only the highest-gradient candidate (splat 1)
    np.testing.assert_allclose(params["means"][10].detach().numpy(), params["means"][1].detach().numpy())
    counts = densify_and_prune(params, torch.zeros(11), grad_threshold=2e-4, split_scale=0.01, min_opacity=0.005,
                               max_scale=0.01)
    assert counts["pruned"] == 5 and len(params) == 6  # the five 5 cm splats


def test_opacity_reset_clamps_and_clears_moments():
    _, params = _params()
    params["opacity_logits"].sum().backward()
    params.optimizer.step()
    params.reset_opacity(0.01)
    assert torch.sigmoid(params["opacity_logits"]).max() <= 0.01 + 1e-7
    assert params.optimizer.state[params["opacity_logits"]]["exp_avg"].abs().sum() == 0


def test_presets_share_one_schedule():
    full = SplatTrainConfig.preset("30k")
    assert (full.iterations, full.densify_from, full.densify_until, full.densify_every) == (30000, 500, 15000, 100)
    assert (full.opacity_reset_every, full.sh_degree_every) == (3000, 1000)
    assert full.position_lr(1, 2.0) == pytest.approx(3.2e-4)
    assert full.position_lr(30000, 2.0) == pytest.approx(3.2e-6)
    small = SplatTrainConfig.preset("cpu-small")
    steps = range(1, small.iterations + 1)
    assert sum(small.densify_at(s) for s in steps) > 10
    assert sum(small.reset_opacity_at(s) for s in steps) >= 2
    assert small.sh_degree_at(small.iterations // 2) == 3
    assert [full.densify_at(s) for s in range(1, 20001)] == [500 < s < 15000 and s % 100 == 0 for s in range(1, 20001)]
    assert [small.densify_at(s) for s in steps] == [10 < s < 300 and s % 2 == 0 for s in steps]
    assert SplatTrainConfig.preset("7k").iterations == 7000


def test_init_from_points():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, (200, 3))
    cloud = init_from_points(pts, rng.uniform(0, 1, (200, 3)), sh_degree=2)
    assert len(cloud) == 200 and cloud.sh_degree == 2 and np.all(cloud.labels == 0)
    np.testing.assert_allclose(cloud.opacities, 0.1, rtol=1e-5)
    from scipy.spatial import cKDTree

    d, _ = cKDTree(pts).query(pts[:1], k=4)
    np.testing.assert_allclose(cloud.scales[0], d[0, 1:].mean(), rtol=1e-5)
    assert np.all(cloud.sh[:, 1:] == 0)


# -------------------------------------------------------------------------------- training
FACES = [(0.9, 0.1, 0.1), (0.1, 0.8, 0.2), (0.1, 0.2, 0.9), (0.9, 0.8, 0.1), (0.9, 0.9, 0.9), (0.6, 0.2, 0.7)]


def _orbit_views(gt: SplatCloud, w: int, h: int, azimuths, elevations, masks: bool, photo_background=(0, 0, 0)):
    """Renders of ``gt`` on an orbit at 35 cm over ``photo_background``; masks = the rendered alpha."""
    K = intrinsics_from_fov(w, h, 60)
    views = []
    for az, el in zip(azimuths, elevations):
        a, e = np.radians(az), np.radians(el)
        T = look_at(0.35 * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)]), [0.0, 0.0, 0.0])
        out = render(gt, K, T, w, h, background=photo_background, device="cpu")
        views.append(TrainView(out.rgb, K, T, mask=out.alpha if masks else None, name=f"az{az}"))
    return views


@pytest.fixture(scope="module")
def box_scene():
    """A 12 x 9 x 10 cm box with six coloured faces (600 splats), 12 training views and 4 held-out views
    (64 x 48, orbit at 35 cm), and a bad start: 300 of its points moved ~5 mm with grey colour."""
    rng = np.random.default_rng(0)
    gt = synthetic.box((0.12, 0.09, 0.10), 600, FACES, rng, sh_degree=3)
    idx = rng.choice(len(gt), 300, replace=False)
    init = init_from_points(gt.means[idx] + rng.normal(0, 0.005, (300, 3)), np.full((300, 3), 0.5))
    return gt, init


@pytest.mark.slow  # 45-60 s: make test-all (make test stays under 15 min)
def test_training_learns_held_out_views(box_scene):
    gt, init = box_scene
    train = _orbit_views(gt, 64, 48, range(0, 360, 30), [20, 50] * 6, masks=False)
    test = _orbit_views(gt, 64, 48, [15, 105, 195, 285], [35] * 4, masks=False)
    config = SplatTrainConfig.preset("cpu-small", max_splats=1500)
    cloud, report = train_splats(init, train, test, config, device="cpu", progress=False)
    assert report["backend"] == "torch" and report["device"] == "cpu"
    assert report["psnr_test_initial"] < 18.0
    assert report["psnr_test"] > 27.0  # measured 30.7 dB (initial 15.6 dB)
    assert report["psnr_train"] > report["psnr_test"] - 5
    assert len(report["loss_history"]) == report["iterations"] == 600
    assert np.mean(report["loss_history"][-50:]) < 0.5 * np.mean(report["loss_history"][:50])
    assert report["densify_events"] and report["n_splats_final"] != report["n_splats_initial"]
    assert len(cloud) == report["n_splats_final"] and cloud.sh_degree == 3 and np.all(cloud.labels == 0)
    # the returned cloud renders like the report says, with the numba renderer
    rendered = [psnr(render(cloud, v.K, v.T_cam_world, 64, 48, device="cpu").rgb, v.image) for v in test]
    assert np.mean(rendered) == pytest.approx(report["psnr_test"], abs=0.05)


def test_a_view_that_sees_no_splat_is_harmless(box_scene):
    gt, init = box_scene
    views = _orbit_views(gt, 32, 24, [0, 90], [30, 30], masks=False)
    away = TrainView(views[0].image, views[0].K, look_at([0.0, 0.0, 0.35], [0.0, 0.0, 1.0]), name="away")
    config = SplatTrainConfig.preset("cpu-small", iterations=6)
    cloud, report = train_splats(init, [views[0], away, views[1]], [], config, device="cpu", progress=False)
    assert len(report["loss_history"]) == 6 and np.isfinite(cloud.means).all()


def test_masked_training_makes_the_outside_transparent(box_scene):
    gt, init = box_scene
    rng = np.random.default_rng(1)
    # floaters: 100 splats in a shell around the box, nothing there in the photos
    d = rng.normal(size=(100, 3))
    floaters = init_from_points(0.1 * d / np.linalg.norm(d, axis=1, keepdims=True), rng.uniform(0, 1, (100, 3)))
    floaters = floaters.replace(opacity_logits=np.full(100, 1.0))
    from pegasus_gen.splats.cloud import concatenate

    start = concatenate([init, floaters])
    # a yellow backdrop in the photos: ignoring the masks would grow splats over it (measured alpha 0.92)
    train = _orbit_views(gt, 48, 36, range(0, 360, 30), [20, 50] * 6, masks=True, photo_background=(0.8, 0.7, 0.3))
    outside = [v.mask < 0.01 for v in train]

    def alpha_outside(cloud):
        return np.mean([render(cloud, v.K, v.T_cam_world, 48, 36, device="cpu").alpha[o].mean()
                        for v, o in zip(train, outside)])

    def alpha_inside(cloud):
        return np.mean([render(cloud, v.K, v.T_cam_world, 48, 36, device="cpu").alpha[v.mask > 0.99].mean()
                        for v in train])

    config = SplatTrainConfig.preset("cpu-small", iterations=250, opacity_reset_every=1000, max_splats=1000)
    cloud, report = train_splats(start, train, [], config, device="cpu", progress=False)
    assert report["psnr_test"] is None
    before = alpha_outside(start)
    assert before > 0.1  # the floaters start clearly visible outside the mask
    assert alpha_outside(cloud) < 0.05  # measured 0.015 (0.92 when the same photos are given without masks)
    assert alpha_inside(cloud) > 0.9


def test_bad_inputs_are_rejected():
    K = intrinsics_from_fov(8, 6, 60)
    with pytest.raises(ValueError, match="mask"):
        TrainView(np.zeros((6, 8, 3)), K, np.eye(4), mask=np.zeros((5, 8)))
    with pytest.raises(ValueError, match="rigid"):
        TrainView(np.zeros((6, 8, 3)), K, np.diag([2.0, 1, 1, 1]))
    with pytest.raises(ValueError, match="backend"):
        rasterizer_torch.rasterize(*tensors(random_cloud(np.random.default_rng(0), 3)), K, np.eye(4), 8, 6,
                                   backend="vulkan")
    from pegasus_gen.errors import PegasusError

    with pytest.raises(PegasusError, match="preset"):
        SplatTrainConfig.preset("100k")


# ------------------------------------------------------------------------------------ CUDA
@pytest.mark.gpu
@pytest.mark.skipif(not rasterizer_torch.gsplat_available(), reason="needs CUDA and gsplat")
def test_gsplat_backend_matches_torch_backend():
    cloud = random_cloud(np.random.default_rng(0), 2000, sh_degree=3, extent=0.3)
    w, h = 96, 72
    K = intrinsics_from_fov(w, h, 60)
    T = look_at([0.9, -0.6, 0.5], [0.0, 0.0, 0.0])
    outs = {}
    for backend in ("torch", "gsplat"):
        leaves = tensors(cloud, requires_grad=True, device="cuda")
        out = rasterizer_torch.rasterize(*leaves, K, T, w, h, background=(0.2, 0.4, 0.6), sh_degree=2,
                                         backend=backend)
        out.rgb.mean().backward()
        outs[backend] = (out, leaves)
    (t_out, t_leaves), (g_out, g_leaves) = outs["torch"], outs["gsplat"]
    assert g_out.backend == "gsplat"
    assert (t_out.rgb - g_out.rgb).abs().mean() < 1 / 255
    assert (t_out.alpha - g_out.alpha).abs().mean() < 1e-3
    vis = t_out.visible & g_out.visible
    assert vis.float().mean() > 0.9
    assert (t_out.means2d[vis] - g_out.means2d[vis]).abs().max() < 1e-2
    assert g_out.means2d_grad().shape == (len(cloud), 2)
    g_t, g_g = t_leaves[0].grad.flatten(), g_leaves[0].grad.flatten()
    assert torch.nn.functional.cosine_similarity(g_t, g_g, dim=0) > 0.9


@pytest.mark.gpu
@pytest.mark.skipif(not rasterizer_torch.gsplat_available(), reason="needs CUDA and gsplat")
def test_training_on_cuda_with_gsplat(box_scene):
    gt, init = box_scene
    train = _orbit_views(gt, 64, 48, range(0, 360, 30), [20, 50] * 6, masks=False)
    test = _orbit_views(gt, 64, 48, [15, 105, 195, 285], [35] * 4, masks=False)
    _, report = train_splats(init, train, test, SplatTrainConfig.preset("cpu-small"), device="cuda",
                             progress=False)
    assert report["backend"] == "gsplat"
    assert report["psnr_test"] > 27.0
    assert report["densify_events"] and report["n_splats_final"] != report["n_splats_initial"]

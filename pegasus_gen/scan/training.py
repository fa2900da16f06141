"""3D Gaussian Splatting training: fit a :class:`SplatCloud` to posed photos (the last step of a scan).

The recipe is the INRIA 3DGS one (gsplat's DefaultStrategy numbers): Adam per parameter group, position
learning rate decaying exponentially from 1.6e-4 to 1.6e-6 times the scene scale over the run, loss
0.8 L1 + 0.2 (1 - SSIM), adaptive density control (clone small / split large splats with a large average
view-space gradient, prune transparent and oversized ones), periodic opacity reset and an SH degree
ramp. One schedule implementation, parameterised by iteration counts in :class:`SplatTrainConfig`;
the presets only choose those numbers ("cpu-small" is the 30k schedule compressed 50x).

Rendering goes through :func:`pegasus_gen.render.differentiable.rasterize` ("torch" on any device, "gsplat"
on CUDA). Masked views (object scans): the target is ``image * mask + bg * (1 - mask)`` and the render
is composited over the same ``bg``, a random colour each iteration, so splats outside the mask must
become transparent; evaluation uses the fixed ``config.background``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field
from tqdm import tqdm

from pegasus_gen.errors import PegasusError
from pegasus_gen.render import differentiable as rasterizer_torch
from pegasus_gen.scan.densify import DensityControl
from pegasus_gen.scan.splat_params import SplatParams
from pegasus_gen.splats import sh as shlib
from pegasus_gen.splats.cloud import SplatCloud, is_rigid


# ------------------------------------------------------------------------------------ inputs
@dataclass
class TrainView:
    """One posed photo.

    image [H, W, 3] float32 in [0, 1]; K [3, 3] OpenCV intrinsics (pixels, pixel (u, v) centred at (u, v));
    T_cam_world [4, 4] world -> camera (metres); mask [H, W] float in [0, 1] (1: object pixel) or None;
    name: for reports.
    """

    image: np.ndarray
    K: np.ndarray
    T_cam_world: np.ndarray
    mask: Optional[np.ndarray] = None
    name: str = ""

    def __post_init__(self):
        self.image = np.ascontiguousarray(self.image, dtype=np.float32)
        self.K = np.asarray(self.K, dtype=np.float64)
        self.T_cam_world = np.asarray(self.T_cam_world, dtype=np.float64)
        if self.image.ndim != 3 or self.image.shape[2] != 3:
            raise ValueError(f"view {self.name!r}: image must be [H, W, 3], got {self.image.shape}")
        if self.K.shape != (3, 3) or self.K[0, 0] <= 0 or self.K[1, 1] <= 0:
            raise ValueError(f"view {self.name!r}: K must be a 3x3 intrinsic matrix with fx, fy > 0")
        if self.T_cam_world.shape != (4, 4) or not is_rigid(self.T_cam_world):
            raise ValueError(f"view {self.name!r}: T_cam_world must be a rigid 4x4 transform")
        if self.mask is not None:
            self.mask = np.ascontiguousarray(self.mask, dtype=np.float32)
            if self.mask.shape != self.image.shape[:2]:
                raise ValueError(f"view {self.name!r}: mask must be [H, W] = {self.image.shape[:2]}, "
                                 f"got {self.mask.shape}")

    @property
    def width(self) -> int:
        return self.image.shape[1]

    @property
    def height(self) -> int:
        return self.image.shape[0]

    @property
    def camera_center(self) -> np.ndarray:
        """[3] camera centre in world coordinates (m)."""
        R, t = self.T_cam_world[:3, :3], self.T_cam_world[:3, 3]
        return -R.T @ t


def init_from_points(points: np.ndarray, colors: np.ndarray, sh_degree: int = 3) -> SplatCloud:
    """Initial splats from an SfM point cloud: points [N, 3] (m), colors [N, 3] in [0, 1].

    Isotropic splats with std-dev = mean distance to the 3 nearest neighbours, identity rotation,
    opacity 0.1, SH DC from the colour and higher bands zero (``sh_degree`` sets K), labels 0.
    """
    from scipy.spatial import cKDTree

    points = np.asarray(points, dtype=np.float64)
    colors = np.asarray(colors, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or colors.shape != points.shape or len(points) < 2:
        raise ValueError(f"need points [N, 3] and colors [N, 3] with N >= 2, got {points.shape}, {colors.shape}")
    k = min(4, len(points))
    dist, _ = cKDTree(points).query(points, k=k)  # column 0 is the point itself
    scale = np.maximum(dist[:, 1:].mean(axis=1), 1e-7)
    n = len(points)
    sh = np.zeros((n, shlib.num_coeffs(sh_degree), 3))
    sh[:, 0] = shlib.rgb_to_sh_dc(np.clip(colors, 0.0, 1.0))
    opacity = 0.1
    return SplatCloud(means=points, quats_wxyz=np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)),
                      log_scales=np.repeat(np.log(scale)[:, None], 3, axis=1),
                      opacity_logits=np.full(n, math.log(opacity / (1 - opacity))), sh=sh,
                      labels=np.zeros(n, np.int32))


# ------------------------------------------------------------------------------------ config
# The standard 3DGS schedule (iterations), as in the INRIA code and gsplat's DefaultStrategy.
STANDARD_SCHEDULE = {"densify_from": 500, "densify_until": 15_000, "densify_every": 100,
                     "opacity_reset_every": 3000, "sh_degree_every": 1000}
# preset: (iterations, factor applied to STANDARD_SCHEDULE, max_splats). cpu-small caps growth: its
# compressed schedule densifies after only 10 steps, while colours are still wrong and every splat has a
# large gradient, and would otherwise multiply the count ~80x (a 300-splat start reached 24k).
PRESETS = {"30k": (30_000, 1.0, None), "7k": (7_000, 1.0, None), "cpu-small": (600, 1.0 / 50.0, 10_000)}


class SplatTrainConfig(BaseModel):
    """Every training knob; build one with :meth:`preset`. Iteration counts are 1-based steps."""

    model_config = ConfigDict(extra="forbid")

    iterations: int = Field(default=30_000, ge=1)
    sh_degree: int = Field(default=3, ge=0, le=3)
    sh_degree_every: int = Field(default=1000, ge=1)  # SH degree +1 every this many steps
    # learning rates (Adam); positions are multiplied by the scene scale and decay log-linearly
    lr_means: float = 1.6e-4
    lr_means_final: float = 1.6e-6
    lr_sh_dc: float = 2.5e-3
    lr_sh_rest: float = 2.5e-3 / 20
    lr_opacity: float = 5e-2
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    ssim_weight: float = Field(default=0.2, ge=0.0, le=1.0)  # loss = (1-w) L1 + w (1 - SSIM)
    # adaptive density control
    densify_from: int = Field(default=500, ge=0)
    densify_until: int = Field(default=15_000, ge=0)
    densify_every: int = Field(default=100, ge=1)
    grad_threshold: float = Field(default=2e-4, gt=0)  # mean |d loss / d mean2d| in NDC units
    percent_dense: float = Field(default=0.01, gt=0)  # clone below, split above this * scene scale
    split_scale_divisor: float = Field(default=1.6, gt=1)
    min_opacity: float = Field(default=0.005, ge=0, lt=1)  # prune below
    max_scale: float = Field(default=0.1, gt=0)  # prune std-dev above this * scene scale (after 1st reset)
    max_splats: Optional[int] = Field(default=None, ge=1)  # growth stops at this count (None: no cap)
    opacity_reset_every: int = Field(default=3000, ge=1)
    opacity_reset_value: float = Field(default=0.01, gt=0, lt=1)
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)  # render/eval background (unmasked + eval)
    random_background: bool = True  # masked views: a random background colour per iteration
    scene_scale: Optional[float] = Field(default=None, gt=0)  # None: 1.1 x camera-centre spread
    seed: int = 0

    @classmethod
    def preset(cls, name: str, **overrides) -> "SplatTrainConfig":
        """``"30k"`` (standard), ``"7k"`` (the standard schedule stopped at 7000 steps) or ``"cpu-small"``
        (600 steps: the 30k schedule with every iteration count divided by 50, so densification, pruning,
        opacity resets and the SH ramp all happen; at most 10k splats). ``overrides`` replace fields."""
        if name not in PRESETS:
            raise PegasusError(f"unknown training preset {name!r}; choose one of {sorted(PRESETS)}")
        iterations, factor, max_splats = PRESETS[name]
        counts = {key: max(1, round(value * factor)) for key, value in STANDARD_SCHEDULE.items()}
        return cls(**{"iterations": iterations, "max_splats": max_splats, **counts, **overrides})

    def position_lr(self, step: int, scene_scale: float) -> float:
        """Position learning rate at ``step`` (1..iterations): log-linear from lr_means to lr_means_final."""
        t = min(max((step - 1) / max(self.iterations - 1, 1), 0.0), 1.0)
        return scene_scale * math.exp((1 - t) * math.log(self.lr_means) + t * math.log(self.lr_means_final))

    def sh_degree_at(self, step: int) -> int:
        """SH bands in use at ``step``: 0 at the start, +1 every ``sh_degree_every`` steps, up to sh_degree."""
        return min(self.sh_degree, step // self.sh_degree_every)

    def densify_at(self, step: int) -> bool:
        return self.densify_from < step < self.densify_until and step % self.densify_every == 0

    def reset_opacity_at(self, step: int) -> bool:
        return step < self.densify_until and step % self.opacity_reset_every == 0


# ------------------------------------------------------------------------------------ losses
def psnr(a, b, max_value: float = 1.0) -> float:
    """Peak signal-to-noise ratio (dB) of two images of equal shape (numpy or torch, values 0..max_value)."""
    a = a.detach().cpu().double().numpy() if isinstance(a, torch.Tensor) else np.asarray(a, np.float64)
    b = b.detach().cpu().double().numpy() if isinstance(b, torch.Tensor) else np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise ValueError(f"psnr of different shapes {a.shape} and {b.shape}")
    mse = float(np.mean((a - b) ** 2))
    return math.inf if mse == 0 else 10.0 * math.log10(max_value**2 / mse)


def _gaussian_window(size: int, sigma: float, dtype, device) -> torch.Tensor:
    x = torch.arange(size, dtype=dtype, device=device) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    g = g / g.sum()
    return g[:, None] * g[None, :]


def ssim(a: torch.Tensor, b: torch.Tensor, window: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Mean structural similarity of images a, b [H, W, C] in [0, 1] (Gaussian window 11x11, sigma 1.5,
    zero-padded 'same' convolution as in 3DGS). Returns a scalar tensor (1 for identical images)."""
    c = a.shape[-1]
    w = _gaussian_window(window, sigma, a.dtype, a.device).expand(c, 1, window, window)
    x, y = a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None]

    def blur(t):
        return torch.nn.functional.conv2d(t, w, padding=window // 2, groups=c)

    mu_x, mu_y = blur(x), blur(y)
    var_x = blur(x * x) - mu_x**2
    var_y = blur(y * y) - mu_y**2
    cov = blur(x * y) - mu_x * mu_y
    c1, c2 = 0.01**2, 0.03**2
    s = ((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2))
    return s.mean()


def _resolve_device_backend(device: str, backend: str) -> tuple[str, str]:
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    if device not in ("cpu", "cuda"):
        raise PegasusError(f"training device must be 'cpu', 'cuda' or 'auto', got {device!r}")
    if device == "cuda" and not torch.cuda.is_available():
        raise PegasusError("training device 'cuda' requested but torch sees no CUDA GPU")
    if backend == "auto":
        backend = "gsplat" if device == "cuda" and rasterizer_torch.gsplat_available() else "torch"
    if backend not in rasterizer_torch.BACKENDS:
        raise PegasusError(f"training backend must be 'auto', 'torch' or 'gsplat', got {backend!r}")
    if backend == "gsplat" and device != "cuda":
        raise PegasusError("the gsplat backend needs device 'cuda'")
    return device, backend


def scene_scale_of(views: Sequence[TrainView], points: np.ndarray | None = None) -> float:
    """Scene scale (m) as in 3DGS: 1.1 x the largest camera-centre distance from their mean; with fewer
    than two distinct cameras, 1.1 x the radius of ``points`` [N, 3] around their mean."""
    centres = np.array([v.camera_center for v in views])
    radius = float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) if len(centres) else 0.0
    if radius < 1e-6 and points is not None and len(points):
        radius = float(np.linalg.norm(points - points.mean(0), axis=1).max())
    if radius < 1e-6:
        raise PegasusError("cannot derive a scene scale: cameras coincide and no points; set scene_scale")
    return 1.1 * radius


class _ViewTensors:
    """A view's image/mask on the training device: image [H, W, 3], mask [H, W, 1] or None."""

    def __init__(self, view: TrainView, device: str):
        self.view = view
        self.image = torch.from_numpy(view.image).to(device)
        self.mask = None if view.mask is None else torch.from_numpy(view.mask).to(device)[..., None]

    def target(self, background: torch.Tensor) -> torch.Tensor:
        """[H, W, 3] the photo with the background replaced outside the mask (unchanged without one)."""
        if self.mask is None:
            return self.image
        return self.image * self.mask + background * (1.0 - self.mask)


def _render(params: SplatParams, view: TrainView, background: torch.Tensor, sh_degree: int, backend: str):
    return rasterizer_torch.rasterize(
        params["means"], params["quats_wxyz"], params["log_scales"], params["opacity_logits"], params.sh(),
        view.K, view.T_cam_world, view.width, view.height, background=background, sh_degree=sh_degree,
        backend=backend)


@torch.no_grad()
def _mean_psnr(params: SplatParams, views: list[_ViewTensors], background: torch.Tensor, sh_degree: int,
               backend: str) -> float | None:
    if not views:
        return None
    values = [psnr(_render(params, v.view, background, sh_degree, backend).rgb.clamp(0, 1), v.target(background))
              for v in views]
    return float(np.mean(values))


def train_splats(init: SplatCloud, train_views: Sequence[TrainView], test_views: Sequence[TrainView] = (),
                 config: SplatTrainConfig | None = None, device: str = "auto", backend: str = "auto",
                 progress: bool = True) -> tuple[SplatCloud, dict]:
    """Optimise ``init`` (world frame, m) to reproduce ``train_views``.

    device "cpu", "cuda" or "auto"; backend "torch", "gsplat" or "auto" (gsplat on CUDA when it imports,
    else torch). Returns (trained SplatCloud with SH degree ``config.sh_degree`` and labels 0, report) where
    report holds psnr_test / psnr_test_initial (mean dB over ``test_views``, None without any), psnr_train,
    n_splats_initial, n_splats_final, iterations, seconds (training loop only), device, backend,
    scene_scale, loss_history [iterations] and densify_events (one dict of counts per densification).
    """
    config = config or SplatTrainConfig.preset("cpu-small")
    if len(init) == 0:
        raise PegasusError("cannot train an empty splat cloud")
    if not train_views:
        raise PegasusError("no training views")
    device, backend = _resolve_device_backend(device, backend)
    scale = config.scene_scale or scene_scale_of(train_views, init.means)
    params = SplatParams(init.with_sh_degree(config.sh_degree).with_label(0), {
        "means": config.position_lr(1, scale), "quats_wxyz": config.lr_quats, "log_scales": config.lr_scales,
        "opacity_logits": config.lr_opacity, "sh_dc": config.lr_sh_dc, "sh_rest": config.lr_sh_rest}, device)
    train = [_ViewTensors(v, device) for v in train_views]
    test = [_ViewTensors(v, device) for v in test_views]
    fixed_bg = torch.tensor(config.background, dtype=torch.float32, device=device)
    generator = torch.Generator().manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    report = {"n_splats_initial": len(params), "device": device, "backend": backend, "scene_scale": scale,
              "psnr_test_initial": _mean_psnr(params, test, fixed_bg, config.sh_degree, backend)}
    density = DensityControl(config, scale, len(params), device, generator)
    losses, events, order = [], [], []
    start = time.perf_counter()
    bar = tqdm(total=config.iterations, desc="train splats", unit="it", disable=not progress)
    for step in range(1, config.iterations + 1):
        if not order:
            order = list(rng.permutation(len(train)))
        view = train[order.pop()]
        params.set_lr("means", config.position_lr(step, scale))
        if view.mask is not None and config.random_background:
            bg = torch.rand(3, generator=generator).to(device)
        else:
            bg = fixed_bg
        out = _render(params, view.view, bg, config.sh_degree_at(step), backend)
        target = view.target(bg)
        loss = (1 - config.ssim_weight) * (out.rgb - target).abs().mean()
        if config.ssim_weight > 0:
            loss = loss + config.ssim_weight * (1.0 - ssim(out.rgb, target))
        if loss.requires_grad:  # False when no splat reaches this view: nothing to learn from it
            loss.backward()
        density.accumulate(out, view.view.width, view.view.height, step)
        params.optimizer.step()
        params.optimizer.zero_grad(set_to_none=True)
        event = density.update(params, step)
        if event is not None:
            events.append(event)
        losses.append(float(loss.detach()))
        bar.update(1)
        if step % 10 == 0 or step == config.iterations:
            bar.set_postfix(loss=f"{losses[-1]:.4f}", splats=len(params))
    bar.close()
    report["seconds"] = time.perf_counter() - start
    report.update({
        "iterations": config.iterations, "n_splats_final": len(params), "loss_history": losses,
        "densify_events": events,
        "psnr_test": _mean_psnr(params, test, fixed_bg, config.sh_degree, backend),
        "psnr_train": _mean_psnr(params, train, fixed_bg, config.sh_degree, backend)})
    return params.to_cloud(), report


__all__ = ["TrainView", "SplatTrainConfig", "init_from_points", "train_splats", "psnr", "ssim", "scene_scale_of",
           "PRESETS", "STANDARD_SCHEDULE"]

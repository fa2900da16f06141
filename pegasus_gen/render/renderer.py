"""Render composed Gaussian-splat scenes: one function, a numba CPU backend and a gsplat CUDA backend.

``render(scene, K, T_cam_world, width, height)`` returns colour, z-depth, alpha and instance labels.
The scene is one :class:`SplatCloud` or a sequence of them (e.g. an environment plus posed objects),
rendered together without concatenating their splat arrays.
"""

from __future__ import annotations

import functools
import logging
import os
import resource
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from pegasus_gen.errors import PegasusError
from pegasus_gen.render import cpu as rasterizer_cpu
from pegasus_gen.render.cpu import NEAR_PLANE, low_pass
from pegasus_gen.splats.cloud import SplatCloud, is_rigid

log = logging.getLogger("pegasus.render")

DEFAULT_ALPHA_MIN = 0.5  # depth is reported where the accumulated alpha reaches this
BYTES_PER_PIXEL = 80  # host memory of a render per pixel, its PNGs included (65 measured on the CPU backend)
BYTES_PER_LABEL_PIXEL = 4  # and per pixel of each requested label's blend weights (float32)


@dataclass
class RenderOutput:
    """Images for one camera; H x W, OpenCV pixel grid.

    rgb [H, W, 3] float32 in [0, 1] (background blended in, clamped);
    depth [H, W] float32 z-depth in metres, sum(w z) / alpha, 0 where alpha < alpha_min;
    alpha [H, W] float32 accumulated opacity;
    label [H, W] int32: per pixel the label with the largest accumulated blend weight, -1 where none;
    label_weights [L, H, W] float32: accumulated blend weight of each requested label (``labels``);
    labels: the requested labels, in the order of ``label_weights``;
    backend: "cpu" or "cuda".
    """

    rgb: np.ndarray
    depth: np.ndarray
    alpha: np.ndarray
    label: np.ndarray
    label_weights: np.ndarray
    labels: tuple
    backend: str

    def mask(self, label: int) -> np.ndarray:
        """[H, W] bool: pixels where ``label`` has the largest blend weight."""
        return self.label == label


def _as_parts(scene) -> list[SplatCloud]:
    parts = [scene] if isinstance(scene, SplatCloud) else list(scene)
    if not all(isinstance(p, SplatCloud) for p in parts):
        raise TypeError("scene must be a SplatCloud or a sequence of SplatClouds")
    return parts


def _check_camera(K, T_cam_world, width, height):
    K = np.asarray(K, dtype=np.float64)
    T = np.asarray(T_cam_world, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K must be a finite 3x3 intrinsic matrix with fx, fy > 0, got {K.tolist()}")
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError("T_cam_world must be a finite 4x4 matrix")
    if not is_rigid(T):
        raise ValueError("T_cam_world must be a rigid transform (orthonormal rotation, det +1)")
    if int(width) != width or int(height) != height or width <= 0 or height <= 0:
        raise ValueError(f"width and height must be positive integers, got {width} x {height}")
    return K, T, int(width), int(height)


def _read_text(path: str) -> str:
    """The text of a small system file, empty where it does not exist."""
    try:
        with open(path) as f:
            return f.read()
    except OSError:
        return ""


def memory_available() -> int:
    """Bytes this process can still allocate, as the system tells: its available memory (Linux's
    MemAvailable, else the physical memory), capped by the cgroup's memory.max and the address-space limit
    (ulimit -v) less what the process already maps."""
    page = os.sysconf("SC_PAGE_SIZE")
    limits = [os.sysconf("SC_PHYS_PAGES") * page]
    meminfo = _read_text("/proc/meminfo").split("MemAvailable:")
    if len(meminfo) == 2:
        limits.append(int(meminfo[1].split()[0]) * 1024)  # kB
    cgroup_max, cgroup_used = (_read_text(f"/sys/fs/cgroup/memory.{k}").strip() for k in ("max", "current"))
    if cgroup_max.isdigit() and cgroup_used.isdigit():
        limits.append(int(cgroup_max) - int(cgroup_used))
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        mapped = int((_read_text("/proc/self/statm").split() or ["0"])[0]) * page
        limits.append(soft - mapped)
    return max(min(limits), 0)


def check_image_memory(width: int, height: int, labels: int = 0) -> None:
    """Refuse (PegasusError) an image of width x height pixels, with ``labels`` requested label weights,
    whose render would need more memory than :func:`memory_available` (checked before anything is allocated)."""
    need = width * height * (BYTES_PER_PIXEL + BYTES_PER_LABEL_PIXEL * labels)
    available = memory_available()
    if need > available:
        raise PegasusError(f"a {width} x {height} image needs about {need / 1e9:,.1f} GB of memory to render, "
                           f"more than the {available / 1e9:,.1f} GB available")


def render(scene: SplatCloud | Sequence[SplatCloud], K: np.ndarray, T_cam_world: np.ndarray,
           width: int, height: int, background=(0.0, 0.0, 0.0), labels: Sequence[int] = (),
           device: str = "auto", near: float = NEAR_PLANE, far: float = 1e10,
           alpha_min: float = DEFAULT_ALPHA_MIN, antialiased: bool = False) -> RenderOutput:
    """Render ``scene`` for an OpenCV pinhole camera.

    scene: a SplatCloud or a sequence of them (world frame); K [3, 3] intrinsics (pixels);
    T_cam_world [4, 4] world->camera; width, height in pixels; background [3] in [0, 1];
    labels: labels whose per-pixel blend weights to return; device "cpu", "cuda" or "auto"
    (CUDA when torch sees a GPU and gsplat works, else CPU; the choice is logged and returned);
    antialiased: Mip-Splatting's 2D filter: a low-pass of EPS2D_ANTIALIASED (0.1 px^2, a one-pixel box) instead
    of 3DGS's EPS2D (0.3), each splat's opacity scaled by what it spreads the splat over (gsplat's antialiased
    mode): without it a surface's splats seen edge-on widen its silhouette by about a pixel on each side (flat
    splats of a mesh at 32 px across: 7.4 % classic, 2.6 % antialiased); splats trained without it (3DGS scans)
    are drawn as trained without it.
    """
    parts = _as_parts(scene)
    K, T, width, height = _check_camera(K, T_cam_world, width, height)
    background = np.asarray(background, dtype=np.float64).reshape(3)
    requested = tuple(int(v) for v in labels)
    check_image_memory(width, height, len(requested))
    backend = _choose_backend(device)
    present, label_index = _dense_labels([p.labels for p in parts])
    requested_index = [int(np.searchsorted(present, r)) if r in present else -1 for r in requested]
    if backend == "cuda":
        from pegasus_gen.render import cuda as rasterizer_cuda

        rgb, depth, alpha, label, weights = rasterizer_cuda.render_gsplat(
            parts, label_index, present, requested_index, K, T, width, height, background, near, far,
            low_pass(antialiased), alpha_min, antialiased)
    else:
        rgb, depth, alpha, label, weights = _render_cpu(
            parts, label_index, present, requested_index, K, T, width, height, background, near, far, alpha_min,
            antialiased)
    return RenderOutput(rgb=rgb, depth=depth, alpha=alpha, label=label, label_weights=weights, labels=requested,
                        backend=backend)


def _render_cpu(parts, label_index, present, requested_index, K, T, width, height, background, near, far,
                alpha_min, antialiased):
    """Numba backend; returns (rgb, depth, alpha, label, weights) as the CUDA backend's ``render_gsplat``."""
    proj = project_cpu(parts, K, T, width, height, near, far, antialiased)
    lab = np.concatenate(label_index) if label_index else np.zeros(0, np.int32)
    rgb, depth_sum, trans, label_dense, weights = rasterizer_cpu.rasterize(
        proj["offsets"], proj["ids"], proj["mean2d"], proj["conic"], proj["depth"], proj["depth_grad"], proj["box"],
        proj["rgb"], proj["log_opacity"], lab, max(len(present), 1), np.asarray(requested_index, dtype=np.int64),
        width, height, background)
    alpha = 1.0 - trans
    label = np.where(label_dense >= 0, present[np.maximum(label_dense, 0)] if len(present) else -1, -1)
    depth = np.where(alpha >= alpha_min, depth_sum / np.maximum(alpha, 1e-12), 0.0)
    return (np.clip(rgb, 0.0, 1.0).astype(np.float32), depth.astype(np.float32), alpha.astype(np.float32),
            label.astype(np.int32), weights)


def project_cpu(parts, K, T, width, height, near=NEAR_PLANE, far=1e10, antialiased=False) -> dict:
    """The numba projection of the splats of ``parts`` (concatenated in order, N in all) for one camera, binned
    to tiles: the inputs of :func:`pegasus_gen.render.cpu.rasterize` by name (``project``'s outputs with N
    rows, and ``offsets``, ``ids`` of the tile lists)."""
    R = np.ascontiguousarray(T[:3, :3])
    t = np.ascontiguousarray(T[:3, 3])
    cam_center = -R.T @ t
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    n = sum(len(p) for p in parts)
    out = {"valid": np.empty(n, dtype=bool), "mean2d": np.empty((n, 2)), "conic": np.empty((n, 3)),
           "depth": np.empty(n), "depth_grad": np.empty((n, 3)), "box": np.empty((n, 4), np.int32),
           "rgb": np.empty((n, 3)), "log_opacity": np.empty(n)}
    start = 0
    for part in parts:
        end = start + len(part)
        if end > start:
            rasterizer_cpu.project(
                part.means, part.quats_wxyz, part.log_scales, part.opacity_logits, part.sh,
                R, t, cam_center, fx, fy, cx, cy, width, height, near, far, low_pass(antialiased), antialiased,
                *(out[k][start:end] for k in ("valid", "mean2d", "conic", "depth", "depth_grad", "box", "rgb",
                                              "log_opacity")))
        start = end
    order = rasterizer_cpu.sort_by_depth(out["depth"], np.flatnonzero(out["valid"]))
    tiles_x = (width + rasterizer_cpu.TILE - 1) // rasterizer_cpu.TILE
    tiles_y = (height + rasterizer_cpu.TILE - 1) // rasterizer_cpu.TILE
    out["offsets"], out["ids"] = rasterizer_cpu.bin_to_tiles(order, out["box"], tiles_x, tiles_x * tiles_y)
    return out


def _dense_labels(labels_per_part: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Map labels to dense indices: (present [L] sorted distinct labels, per part [N_i] int32 index)."""
    mins = [int(lab.min()) for lab in labels_per_part if len(lab)]
    if not mins:
        return np.zeros(0, np.int32), [np.zeros(0, np.int32) for _ in labels_per_part]
    lo, hi = min(mins), max(int(lab.max()) for lab in labels_per_part if len(lab))
    if hi - lo > 1 << 16:  # sparse ids: sort-based
        present = np.unique(np.concatenate(labels_per_part)).astype(np.int32)
        return present, [np.searchsorted(present, lab).astype(np.int32) for lab in labels_per_part]
    single = [len(lab) > 0 and lab.min() == lab.max() for lab in labels_per_part]  # the usual case
    seen = np.zeros(hi - lo + 1, dtype=bool)
    for lab, one in zip(labels_per_part, single):
        seen[(lab[:1] if one else lab) - lo] = True
    present = np.flatnonzero(seen)
    lookup = np.zeros(hi - lo + 1, np.int32)
    lookup[present] = np.arange(len(present), dtype=np.int32)
    index = [np.full(len(lab), lookup[lab[0] - lo], np.int32) if one else lookup[lab - lo]
             for lab, one in zip(labels_per_part, single)]
    return (present + lo).astype(np.int32), index


@functools.lru_cache(maxsize=1)
def cuda_status() -> tuple[bool, str]:
    """(usable, reason): whether the gsplat CUDA backend works here, with the reason when it does not."""
    import importlib.util

    if importlib.util.find_spec("gsplat") is None:
        return False, "gsplat is not installed (pip install '.[cuda]' on a CUDA machine)"
    try:
        import torch
    except ImportError:
        return False, "torch is not installed"
    if not torch.cuda.is_available():
        return False, "torch sees no CUDA GPU"
    try:
        import gsplat  # noqa: F401
    except Exception as exc:  # gsplat missing or broken
        return False, f"gsplat is not usable ({exc.__class__.__name__}: {exc}); pip install '.[cuda]'"
    try:
        from pegasus_gen.render import cuda as rasterizer_cuda

        rasterizer_cuda.smoke_test()
    except Exception as exc:  # e.g. its CUDA code failed to compile
        return False, f"gsplat failed on this GPU ({exc.__class__.__name__}: {exc})"
    return True, "gsplat on " + torch.cuda.get_device_name(0)


def _choose_backend(device: str) -> str:
    if device == "cpu":
        return "cpu"
    if device not in ("cuda", "auto"):
        raise PegasusError(f"render device must be 'cpu', 'cuda' or 'auto', got {device!r}")
    ok, reason = cuda_status()
    if device == "cuda":
        if not ok:
            raise PegasusError(f"render device 'cuda' is not available: {reason}")
        return "cuda"
    _log_auto_choice(ok, reason)
    return "cuda" if ok else "cpu"


@functools.lru_cache(maxsize=None)
def _log_auto_choice(ok: bool, reason: str) -> None:
    if ok:
        log.info("render device auto: using CUDA (%s)", reason)
    else:
        log.info("render device auto: using CPU (numba) because %s", reason)


"""gsplat CUDA backend of :func:`pegasus_gen.render.renderer.render` (needs torch with CUDA and
``pip install '.[cuda]'``).

Each part of a scene (a SplatCloud) is uploaded once and kept on the GPU while it lives, and a scene's parts
are concatenated there once while the same parts are rendered again (the frames of a static scene). Per frame:
colour from gsplat's SH evaluation; the instance labels as one-hot feature channels through the same blend;
depth by the CPU renderer's rule, each splat's depth on a pixel's ray being a plane A + B u + C v over the image
(:func:`pegasus_gen.render.differentiable.depth_planes`), rendered as three feature channels and evaluated per
pixel (the CPU's clamp at 3.33 standard deviations of z aside: tests/test_depth_planes.py measures what it
changes). gsplat samples pixel (u, v) at (u + 0.5, v + 0.5), so the principal point is shifted by +0.5 to keep
the OpenCV convention of the CPU backend. The images come back to the host in one float32 copy.
"""

from __future__ import annotations

import weakref

import numpy as np
import torch

from pegasus_gen.render.differentiable import depth_planes

_PARTS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()  # SplatCloud -> its device tensors
_SCENE: dict = {}  # the last scene rendered: "parts" (weak references) and its concatenated device tensors


def _part_on_gpu(cloud, device) -> dict:
    """Device tensors of one cloud (uploaded on first use, kept while the cloud lives)."""
    cached = _PARTS.get(cloud)
    if cached is None:
        cached = _PARTS[cloud] = {
            "means": torch.from_numpy(cloud.means).to(device, torch.float32),
            "quats": torch.from_numpy(cloud.quats_wxyz).to(device, torch.float32),
            "log_scales": torch.from_numpy(cloud.log_scales).to(device, torch.float32),
            "opacity_logits": torch.from_numpy(cloud.opacity_logits).to(device, torch.float32),
            "sh": torch.from_numpy(cloud.sh).to(device, torch.float32)}
    return cached


def _scene_on_gpu(parts, label_index, device) -> dict:
    """Device tensors of the splats of ``parts`` concatenated (each part uploaded once while it lives; the
    concatenation made again only when the parts differ from the last call's): means [N, 3], quats [N, 4],
    log_scales [N, 3], scales [N, 3], opacities [N], sh [N, K, 3] (parts of lower SH degree padded with zeros),
    sh_degree, labels [N] int64 dense label index."""
    refs = _SCENE.get("parts", ())
    if len(refs) == len(parts) and all(r() is p for r, p in zip(refs, parts)):
        return _SCENE
    on_gpu = [_part_on_gpu(p, device) for p in parts]
    k = max(p.sh.shape[1] for p in parts)

    def cat(key):
        return torch.cat([g[key] for g in on_gpu])

    _SCENE.clear()
    _SCENE.update({
        "parts": tuple(weakref.ref(p) for p in parts),
        "means": cat("means"), "quats": cat("quats"), "log_scales": cat("log_scales"),
        "scales": cat("log_scales").exp(), "opacities": torch.sigmoid(cat("opacity_logits")),
        "sh": torch.cat([torch.nn.functional.pad(g["sh"], (0, 0, 0, k - g["sh"].shape[1])) for g in on_gpu]),
        "sh_degree": int(round(k ** 0.5)) - 1,
        "labels": torch.from_numpy(np.concatenate(label_index)).to(device, torch.int64),
    })
    return _SCENE


def render_gsplat(parts, label_index, n_labels, requested_index, K, T_cam_world, width, height, background,
                  near, far, eps2d):
    """Render on CUDA with gsplat.

    parts: SplatClouds; label_index: per part [N_i] int32 dense label index (0..n_labels-1);
    requested_index [R] dense indices (-1: label absent). Returns numpy float32 (rgb [H,W,3] with background,
    depth_sum [H,W] (sum of w z), alpha [H,W]), label_dense [H,W] int32 (-1 where none), weights [R,H,W] float32.
    """
    from gsplat import rasterization, spherical_harmonics

    parts_kept = [(p, idx) for p, idx in zip(parts, label_index) if len(p)]
    if not parts_kept:
        blank = np.zeros((height, width), np.float32)
        return (np.broadcast_to(background, (height, width, 3)).astype(np.float32), blank, blank,
                np.full((height, width), -1, np.int32), np.zeros((len(requested_index), height, width), np.float32))
    device = torch.device("cuda")
    g = _scene_on_gpu([p for p, _ in parts_kept], [idx for _, idx in parts_kept], device)
    T = torch.tensor(T_cam_world, dtype=torch.float32, device=device)
    K_gsplat = torch.tensor(K, dtype=torch.float32, device=device)
    K_gsplat[:2, 2] += 0.5
    with torch.no_grad():
        campos = -T[:3, :3].T @ T[:3, 3]
        rgb = torch.clamp_min(spherical_harmonics(g["sh_degree"], g["means"] - campos, g["sh"]) + 0.5, 0.0)
        onehot = torch.nn.functional.one_hot(g["labels"], n_labels).to(torch.float32)
        # in float64: the planes of needle-like splats lose all their digits to float32's cancellation
        planes = depth_planes(g["means"].double(), g["quats"].double(), g["log_scales"].double(),
                              torch.tensor(K, dtype=torch.float64, device=device),
                              torch.tensor(T_cam_world, dtype=torch.float64, device=device), width, height).float()
        colors, alphas, _ = rasterization(
            g["means"], g["quats"], g["scales"], g["opacities"], torch.cat([rgb, onehot, planes], dim=1),
            viewmats=T[None], Ks=K_gsplat[None], width=width, height=height, near_plane=near, far_plane=far,
            eps2d=eps2d, sh_degree=None, packed=False, render_mode="RGB", rasterize_mode="classic")
        out = colors[0]
        alpha = alphas[0, ..., 0]
        weights = out[..., 3:3 + n_labels]
        best_w, best = weights.max(dim=-1)
        label = torch.where(best_w > 0, best, torch.full_like(best, -1)).to(torch.float32)
        A, B, C = out[..., 3 + n_labels:].unbind(-1)
        v, u = torch.meshgrid(torch.arange(height, device=device, dtype=torch.float32),
                              torch.arange(width, device=device, dtype=torch.float32), indexing="ij")
        bg = torch.tensor(background, dtype=torch.float32, device=device)
        req = [i for i in requested_index if i >= 0]
        images = torch.cat([out[..., :3] + (1.0 - alpha)[..., None] * bg, (A + B * u + C * v)[..., None],
                            alpha[..., None], label[..., None], weights[..., req]], dim=-1).cpu().numpy()
    req_w = np.zeros((len(requested_index), height, width), np.float32)
    req_w[[j for j, i in enumerate(requested_index) if i >= 0]] = np.moveaxis(images[..., 6:], -1, 0)
    return images[..., :3], images[..., 3], images[..., 4], images[..., 5].astype(np.int32), req_w


def smoke_test() -> None:
    """Render one Gaussian on the GPU (compiles gsplat's kernels on first use); raises if that fails."""
    from pegasus_gen.splats.cloud import SplatCloud

    cloud = SplatCloud(np.array([[0.0, 0.0, 2.0]]), np.array([[1.0, 0, 0, 0]]), np.log(np.full((1, 3), 0.1)),
                       np.array([2.0]), np.zeros((1, 1, 3)), np.zeros(1, np.int32))
    K = np.array([[20.0, 0, 7.5], [0, 20.0, 7.5], [0, 0, 1]])
    _, _, alpha, _, _ = render_gsplat([cloud], [np.zeros(1, np.int32)], 1, [], K, np.eye(4), 16, 16,
                                      np.zeros(3), 0.01, 1e10, 0.3)
    if not (np.isfinite(alpha).all() and alpha.max() > 0.5):
        raise RuntimeError("gsplat rendered a wrong test image")

"""gsplat CUDA backend of :func:`pegasus_gen.render.renderer.render` (needs torch with CUDA and
``pip install '.[cuda]'``).

Colour comes from gsplat's own SH evaluation (per part, so parts may differ in SH degree); the
instance labels ride along as one-hot feature channels through the same blend, and depth as gsplat's
"D" channel (sum of w z). gsplat samples pixel (u, v) at (u + 0.5, v + 0.5), so the principal point is
shifted by +0.5 to keep the OpenCV convention of the CPU backend.
Splat arrays are uploaded once per SplatCloud object and kept on the GPU while the object lives.
"""

from __future__ import annotations

import weakref

import numpy as np
import torch

_DEVICE_CACHE: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _on_gpu(cloud, device) -> dict:
    """Device tensors of a cloud (uploaded on first use, cached for the cloud's lifetime)."""
    cached = _DEVICE_CACHE.get(cloud)
    if cached is None:
        cached = {
            "means": torch.from_numpy(cloud.means).to(device),
            "quats": torch.from_numpy(cloud.quats_wxyz).to(device),
            "scales": torch.from_numpy(cloud.log_scales).to(device).exp(),
            "opacities": torch.sigmoid(torch.from_numpy(cloud.opacity_logits).to(device)),
            "sh": torch.from_numpy(cloud.sh).to(device),
        }
        _DEVICE_CACHE[cloud] = cached
    return cached


def render_gsplat(parts, label_index, n_labels, requested_index, K, T_cam_world, width, height, background,
                  near, far, eps2d):
    """Render on CUDA with gsplat.

    parts: SplatClouds; label_index: per part [N_i] int32 dense label index (0..n_labels-1);
    requested_index [R] dense indices (-1: label absent). Returns numpy (rgb [H,W,3] with background,
    depth_sum [H,W], alpha [H,W], label_dense [H,W] int32 (-1 where none), weights [R,H,W]).
    """
    from gsplat import rasterization, spherical_harmonics

    device = torch.device("cuda")
    R = T_cam_world[:3, :3]
    campos = torch.tensor(-R.T @ T_cam_world[:3, 3], dtype=torch.float32, device=device)
    means, quats, scales, opacities, features = [], [], [], [], []
    for part, idx in zip(parts, label_index):
        if len(part) == 0:
            continue
        g = _on_gpu(part, device)
        rgb = spherical_harmonics(part.sh_degree, g["means"] - campos, g["sh"])
        rgb = torch.clamp_min(rgb + 0.5, 0.0)
        onehot = torch.nn.functional.one_hot(torch.from_numpy(idx.astype(np.int64)).to(device), n_labels)
        means.append(g["means"])
        quats.append(g["quats"])
        scales.append(g["scales"])
        opacities.append(g["opacities"])
        features.append(torch.cat([rgb, onehot.to(torch.float32)], dim=1))
    if not means:
        blank = np.zeros((height, width))
        return (np.broadcast_to(background, (height, width, 3)).astype(np.float32), blank, blank,
                np.full((height, width), -1, np.int32), np.zeros((len(requested_index), height, width), np.float32))
    K_gsplat = np.array(K, dtype=np.float64)
    K_gsplat[0, 2] += 0.5
    K_gsplat[1, 2] += 0.5
    with torch.no_grad():
        colors, alphas, _ = rasterization(
            torch.cat(means), torch.cat(quats), torch.cat(scales), torch.cat(opacities), torch.cat(features),
            viewmats=torch.tensor(T_cam_world, dtype=torch.float32, device=device)[None],
            Ks=torch.tensor(K_gsplat, dtype=torch.float32, device=device)[None],
            width=width, height=height, near_plane=near, far_plane=far, eps2d=eps2d,
            sh_degree=None, packed=False, render_mode="RGB+D", rasterize_mode="classic")
        out = colors[0]
        alpha = alphas[0, ..., 0]
        bg = torch.tensor(background, dtype=torch.float32, device=device)
        rgb = out[..., :3] + (1.0 - alpha)[..., None] * bg
        weights = out[..., 3:3 + n_labels]
        best_w, best = weights.max(dim=-1)
        label = torch.where(best_w > 0, best, torch.full_like(best, -1)).to(torch.int32)
        req = torch.tensor([max(i, 0) for i in requested_index], dtype=torch.long, device=device)
        present = torch.tensor([i >= 0 for i in requested_index], dtype=torch.float32, device=device)
        req_w = weights[..., req].permute(2, 0, 1) * present[:, None, None] if len(requested_index) else \
            torch.zeros((0, height, width), device=device)
        depth_sum = out[..., 3 + n_labels]
    return (rgb.cpu().numpy(), depth_sum.double().cpu().numpy(), alpha.double().cpu().numpy(),
            label.cpu().numpy(), req_w.cpu().numpy().astype(np.float32))


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

"""Adaptive density control of 3DGS training, as a strategy the training loop calls (gsplat's
``DefaultStrategy`` in this project's terms): each splat's view-space gradient is accumulated while densification
runs; at the schedule's steps the splats with a large average gradient grow (small ones cloned, large ones
split) and transparent or oversized ones are pruned; the opacities are reset periodically.
"""

from __future__ import annotations

import math

import torch

from pegasus_gen.render import differentiable as rasterizer_torch
from pegasus_gen.scan.splat_params import PARAM_NAMES, SplatParams


@torch.no_grad()
def densify_and_prune(params: SplatParams, grad2d: torch.Tensor, *, grad_threshold: float, split_scale: float,
                      min_opacity: float, max_scale: float | None = None, split_divisor: float = 1.6,
                      max_splats: int | None = None, generator: torch.Generator | None = None) -> dict:
    """Adaptive density control, in place on ``params``.

    grad2d [N]: average view-space gradient norm of each splat's 2D mean (NDC units). Splats with
    grad2d >= grad_threshold grow: those with largest std-dev <= split_scale (m) are cloned (an exact copy),
    larger ones are split into 2 splats drawn from their own Gaussian with std-devs / split_divisor (the
    original is removed). With ``max_splats`` only the highest-gradient candidates grow, within the budget.
    Then splats with opacity < min_opacity, or largest std-dev > max_scale (m, when given), are pruned.
    Returns counts {"cloned", "split", "pruned", "before", "after"}.
    """
    n = len(params)
    if grad2d.shape != (n,):
        raise ValueError(f"grad2d must have shape ({n},), got {tuple(grad2d.shape)}")
    largest = torch.exp(params["log_scales"]).max(dim=1).values
    grow = grad2d >= grad_threshold
    if max_splats is not None:
        budget = max(max_splats - n, 0)  # each clone or split adds one splat
        if int(grow.sum()) > budget:
            top = torch.topk(torch.where(grow, grad2d, torch.full_like(grad2d, -1.0)), budget).indices
            grow = torch.zeros_like(grow)
            grow[top] = True
    clone = grow & (largest <= split_scale)
    split = grow & (largest > split_scale)
    rows = {name: [] for name in PARAM_NAMES}
    if clone.any():
        for name in PARAM_NAMES:
            rows[name].append(params[name][clone])
    if split.any():
        idx = torch.nonzero(split).squeeze(1).repeat(2)
        scales = torch.exp(params["log_scales"][idx])
        noise = torch.randn(scales.shape, generator=generator, device="cpu").to(scales)
        R = rasterizer_torch.quat_to_rotmat(params["quats_wxyz"][idx])
        for name in PARAM_NAMES:
            rows[name].append(params[name][idx])
        rows["means"][-1] = params["means"][idx] + (R @ (scales * noise)[:, :, None])[:, :, 0]
        rows["log_scales"][-1] = params["log_scales"][idx] - math.log(split_divisor)
    n_clone, n_split = int(clone.sum()), int(split.sum())
    if n_clone or n_split:
        params.append({name: torch.cat(parts) for name, parts in rows.items()})
    added = len(params) - n
    removed_split = torch.cat([split, torch.zeros(added, dtype=torch.bool, device=split.device)])
    opacity = torch.sigmoid(params["opacity_logits"])
    prune = opacity < min_opacity
    if max_scale is not None:
        prune |= torch.exp(params["log_scales"]).max(dim=1).values > max_scale
    n_pruned = int((prune & ~removed_split).sum())
    keep = ~(prune | removed_split)
    if not bool(keep.all()):
        params.keep(keep)
    return {"cloned": n_clone, "split": n_split, "pruned": n_pruned, "before": n, "after": len(params)}


# ---------------------------------------------------------------------------------- training


class DensityControl:
    """The densification schedule of ``config`` (a ``SplatTrainConfig``) for a scene of ``scene_scale`` (m):
    ``accumulate`` after each backward pass, ``update`` after each optimiser step (returns the counts of a
    densification, else None)."""

    def __init__(self, config, scene_scale: float, n: int, device, generator: torch.Generator):
        self.config, self.scene_scale, self.generator = config, scene_scale, generator
        self._restart(n, device)

    def _restart(self, n: int, device) -> None:
        self.grad2d = torch.zeros(n, device=device)
        self.count = torch.zeros(n, device=device)

    @torch.no_grad()
    def accumulate(self, out, width: int, height: int, step: int) -> None:
        """Add the view-space gradient norms (pixels of a ``width`` x ``height`` view) of the splats ``out`` (a
        rasterisation whose loss was just back-propagated) saw."""
        if step >= self.config.densify_until:
            return
        g = out.means2d_grad()
        if g is not None:
            norm = torch.stack([g[:, 0] * width / 2, g[:, 1] * height / 2], 1).norm(dim=1)
            self.grad2d += torch.where(out.visible, norm, torch.zeros_like(norm))
            self.count += out.visible.to(self.count.dtype)

    def update(self, params: SplatParams, step: int) -> dict | None:
        """At a densification step: grow and prune ``params`` (``densify_and_prune``; oversized splats only
        after the first opacity reset) and start accumulating afresh; at a reset step, reset the opacities.
        Returns the densification's counts with its step, or None."""
        c, event = self.config, None
        if c.densify_at(step):
            event = {"step": step, **densify_and_prune(
                params, self.grad2d / self.count.clamp_min(1), grad_threshold=c.grad_threshold,
                split_scale=c.percent_dense * self.scene_scale, min_opacity=c.min_opacity,
                max_scale=c.max_scale * self.scene_scale if step > c.opacity_reset_every else None,
                split_divisor=c.split_scale_divisor, max_splats=c.max_splats, generator=self.generator)}
            self._restart(len(params), self.grad2d.device)
        if c.reset_opacity_at(step):
            params.reset_opacity(c.opacity_reset_value)
        return event

"""The trainable tensors of a splat cloud and their Adam optimiser, edited together when splats are added or
removed (densification) or their opacities reset."""

from __future__ import annotations

import math

import numpy as np
import torch

from pegasus_gen.splats.cloud import SplatCloud

PARAM_NAMES = ("means", "quats_wxyz", "log_scales", "opacity_logits", "sh_dc", "sh_rest")


class SplatParams:
    """The trainable tensors of a cloud and their Adam optimiser; densification edits both together.

    Tensors (N rows): means [N, 3] m, quats_wxyz [N, 4], log_scales [N, 3], opacity_logits [N],
    sh_dc [N, 1, 3], sh_rest [N, K-1, 3]. Learning rates: ``lrs`` maps each name to its rate.
    """

    def __init__(self, cloud: SplatCloud, lrs: dict, device: str | torch.device = "cpu"):
        arrays = {"means": cloud.means, "quats_wxyz": cloud.quats_wxyz, "log_scales": cloud.log_scales,
                  "opacity_logits": cloud.opacity_logits, "sh_dc": cloud.sh[:, :1], "sh_rest": cloud.sh[:, 1:]}
        self.params = {name: torch.nn.Parameter(torch.tensor(arrays[name], dtype=torch.float32, device=device))
                       for name in PARAM_NAMES}
        self.optimizer = torch.optim.Adam(
            [{"params": [self.params[name]], "lr": lrs[name], "name": name} for name in PARAM_NAMES],
            eps=1e-15)

    def __len__(self) -> int:
        return self.params["means"].shape[0]

    def __getitem__(self, name: str) -> torch.nn.Parameter:
        return self.params[name]

    def sh(self) -> torch.Tensor:
        """[N, K, 3] all SH coefficients."""
        return torch.cat([self.params["sh_dc"], self.params["sh_rest"]], dim=1)

    def set_lr(self, name: str, lr: float) -> None:
        for group in self.optimizer.param_groups:
            if group["name"] == name:
                group["lr"] = lr

    def _swap(self, name: str, values: torch.Tensor, edit_state) -> None:
        """Replace parameter ``name`` by ``values``; edit_state(moment tensor) -> new moment tensor."""
        old = self.params[name]
        new = torch.nn.Parameter(values.detach().contiguous())
        state = self.optimizer.state.pop(old, None)
        for group in self.optimizer.param_groups:
            if group["name"] == name:
                group["params"] = [new]
        if state:
            self.optimizer.state[new] = {key: edit_state(v) if key in ("exp_avg", "exp_avg_sq") else v
                                         for key, v in state.items()}
        self.params[name] = new

    @torch.no_grad()
    def keep(self, mask: torch.Tensor) -> None:
        """Keep the rows where ``mask`` [N] bool is True (optimiser moments kept with them)."""
        for name in PARAM_NAMES:
            self._swap(name, self.params[name][mask], lambda m: m[mask])

    @torch.no_grad()
    def append(self, rows: dict) -> None:
        """Append rows (dict of PARAM_NAMES -> tensors with M rows); their optimiser moments start at zero."""
        for name in PARAM_NAMES:
            extra = rows[name].to(self.params[name])
            self._swap(name, torch.cat([self.params[name], extra]),
                       lambda m, extra=extra: torch.cat([m, torch.zeros_like(extra)]))

    @torch.no_grad()
    def reset_opacity(self, value: float) -> None:
        """Clamp opacities to at most ``value`` and zero the opacity moments (INRIA's opacity reset)."""
        logit = math.log(value / (1 - value))
        self._swap("opacity_logits", self.params["opacity_logits"].clamp_max(logit), torch.zeros_like)

    def to_cloud(self) -> SplatCloud:
        """The current splats as a numpy SplatCloud (labels 0)."""
        p = {name: t.detach().cpu().numpy() for name, t in self.params.items()}
        return SplatCloud(means=p["means"], quats_wxyz=p["quats_wxyz"], log_scales=p["log_scales"],
                          opacity_logits=p["opacity_logits"], sh=np.concatenate([p["sh_dc"], p["sh_rest"]], 1),
                          labels=np.zeros(len(p["means"]), np.int32))

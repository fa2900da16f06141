"""Training checkpoints: what one holds and how it is read back.

A checkpoint (``torch.save`` of a dict) holds ``format``, ``model`` and ``optimizer`` (and ``scaler``) state,
``epoch`` (epochs done), ``step`` (optimisation steps done), ``model_config`` (``model.model_config``: the
architecture and input normalisation), ``train_config`` (the TrainConfig as a dict), ``object`` (the
TargetObject as a dict) and ``stride``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from dope_training.model import DopeNetwork, build_model
from pegasus_gen.errors import PegasusError

CHECKPOINT_FORMAT = 1


@dataclass
class TargetObject:
    """The object a network is trained for: what PnP, depth refinement and evaluation need without the
    dataset. ``surface_points``/``surface_normals`` [N, 3] (metres, model frame; unit normals): samples of
    the model's surface for depth refinement, None when the training data had no model (DOPE/NDDS folders);
    ``symmetry_axis`` [3]: the axis of a continuous rotational symmetry (model frame), if any."""

    obj_id: int
    name: str
    bbox_min: list[float]  # [3] metres, model frame
    bbox_size: list[float]  # [3] metres
    symmetric: bool = False
    surface_points: list[list[float]] | None = None
    surface_normals: list[list[float]] | None = None
    symmetry_axis: list[float] | None = None


def load_checkpoint(path: str | Path) -> dict:
    """A checkpoint written by training (tensors mapped to the CPU); a clear error for anything else. Only
    tensors and plain containers are unpickled (``weights_only``): a file that would build other objects, and
    so could run code, is refused."""
    path = Path(path)
    if not path.is_file():
        raise PegasusError(f"{path}: no such checkpoint")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several kinds for a damaged, foreign or crafted file
        reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise PegasusError(f"{path}: not a readable checkpoint ({reason})") from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise PegasusError(f"{path}: not a pegasus DOPE checkpoint (format {CHECKPOINT_FORMAT})")
    return state


def model_from_checkpoint(state: dict) -> DopeNetwork:
    """The trained network of a checkpoint, in eval mode on the CPU."""
    model = build_model(state["model_config"])
    model.load_state_dict(state["model"])
    return model.eval()

"""Training checkpoints: what one holds and how it is read back.

A checkpoint (``torch.save`` of a dict) holds ``format``, ``model`` and ``optimizer`` (and ``scaler``) state,
``epoch`` (epochs done), ``step`` (optimisation steps done), ``model_config`` (``model.model_config``: the
architecture and input normalisation), ``train_config`` (the TrainConfig as a dict), ``object`` (the
TargetObject as a dict) and ``stride``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from dope_training.model import DopeNetwork, ModelConfig, build_model, config_from_dict
from pegasus_gen.errors import PegasusError

CHECKPOINT_FORMAT = 1
CHECKPOINT_KEYS = {"format", "model", "optimizer", "scaler", "epoch", "step", "model_config", "train_config", "object",
                   "stride"}


@dataclass
class TargetObject:
    """The object a network is trained for: what PnP, depth refinement and evaluation need without the
    dataset. ``surface_points``/``surface_normals`` [N, 3] (metres, model frame; unit normals): samples of
    the model's surface for depth refinement, None when the training data had no model (DOPE/NDDS folders);
    ``symmetry_axis`` [3]: the axis of a continuous rotational symmetry (model frame), if any; ``keypoints``
    [K + 1, 3] (metres, model frame): the points the network's keypoints are, the centre last
    (``dope_training.keypoints``), None for DOPE's cuboid of the model box (K = 8)."""

    obj_id: int
    name: str
    bbox_min: list[float]  # [3] metres, model frame
    bbox_size: list[float]  # [3] metres
    symmetric: bool = False
    surface_points: list[list[float]] | None = None
    surface_normals: list[list[float]] | None = None
    symmetry_axis: list[float] | None = None
    keypoints: list[list[float]] | None = None


def target_object(doc, where: str, corners: int = 8) -> TargetObject:
    """The TargetObject of ``doc`` (its fields as a dict, as checkpoints and ONNX metadata store it) for a network
    that finds ``corners`` object points besides the centre (``ModelConfig.keypoints``); one clear error naming
    ``where`` for unknown or missing fields, a model box that is not 3 finite numbers (sizes > 0), surface samples
    that are not [N, 3] finite numbers or keypoints that are not [corners + 1, 3] (none: the cuboid, 8)."""
    try:
        obj = TargetObject(**doc)
        box = np.array([obj.bbox_min, obj.bbox_size], dtype=np.float64)
        surface = [np.array(v, dtype=np.float64) for v in (obj.surface_points, obj.surface_normals) if v is not None]
        keypoints = None if obj.keypoints is None else np.array(obj.keypoints, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise PegasusError(f"{where}: not a pegasus object description ({exc})") from None
    if box.shape != (2, 3) or not np.isfinite(box).all() or (box[1] <= 0).any():
        raise PegasusError(f"{where}: the object's model box is not 3 finite numbers (sizes > 0)")
    if any(v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all() for v in surface) or len(surface) == 1:
        raise PegasusError(f"{where}: the object's surface points and normals are not [N, 3] finite numbers")
    if keypoints is not None and (keypoints.shape != (corners + 1, 3) or not np.isfinite(keypoints).all()):
        raise PegasusError(f"{where}: the object's keypoints are not [{corners + 1}, 3] finite numbers (the "
                           f"network finds {corners} points and the centre)")
    if keypoints is None and corners != 8:
        raise PegasusError(f"{where}: the object has no keypoints, and the network finds {corners} points, not the "
                           "cuboid's 8")
    return obj


def load_checkpoint(path: str | Path) -> dict:
    """A checkpoint written by training (tensors mapped to the CPU), checked: its keys, its network's weights
    against its model config, its object and input size; a clear error for anything else. Only tensors and
    plain containers are unpickled (``weights_only``): a file that would build other objects, and so could run
    code, is refused."""
    path = Path(path)
    if not path.is_file():
        raise PegasusError(f"{path}: no such checkpoint")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several kinds for a damaged, foreign or crafted file
        if "weights_only" in str(exc):  # torch's advice there (load it unsafely) is not ours to give
            raise PegasusError(f"{path}: not a readable checkpoint (it holds objects other than tensors and plain "
                               "data, which could run code when loaded; refused)") from None
        reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise PegasusError(f"{path}: not a readable checkpoint ({reason})") from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise PegasusError(f"{path}: not a pegasus DOPE checkpoint (format {CHECKPOINT_FORMAT})")
    missing, unknown = sorted(CHECKPOINT_KEYS - state.keys()), sorted(map(str, state.keys() - CHECKPOINT_KEYS))
    if missing or unknown:
        raise PegasusError(f"{path}: not a pegasus DOPE checkpoint (missing keys: {', '.join(missing) or 'none'}; "
                           f"unknown keys: {', '.join(unknown) or 'none'})")
    if not all(isinstance(state[k], int) and state[k] >= 0 for k in ("epoch", "step")):
        raise PegasusError(f"{path}: epoch and step are not counts")
    config = _check_weights(state, path)
    target_object(state["object"], f"{path}: object", config.keypoints)
    train_config = state["train_config"] if isinstance(state["train_config"], dict) else {}
    size, focal_px = train_config.get("size"), train_config.get("focal_px", 0.0)
    if not isinstance(size, int) or size <= 0 or not isinstance(focal_px, (int, float)) or not 0 <= focal_px < math.inf:
        raise PegasusError(f"{path}: train_config has no input scale (size: a positive integer, focal_px: a "
                           "finite number >= 0, px)")
    return state


def _check_weights(state: dict, path: Path) -> ModelConfig:
    """``state["model_config"]``'s ModelConfig; a PegasusError unless ``state["model"]`` holds exactly the weights,
    with their shapes, of the network it describes (compared on torch's meta device: nothing allocated)."""
    config = config_from_dict(state["model_config"], f"{path}: model_config")
    with torch.device("meta"):
        expected = {k: v.shape for k, v in build_model(config).state_dict().items()}
    weights = state["model"] if isinstance(state["model"], dict) else {}
    missing, unknown = sorted(expected.keys() - weights.keys()), sorted(map(str, weights.keys() - expected.keys()))
    wrong = sorted(k for k in expected.keys() & weights.keys()
                   if not isinstance(weights[k], torch.Tensor) or weights[k].shape != expected[k])
    if missing or unknown or wrong:
        detail = "; ".join(f"{what}: {', '.join(keys[:3])}{' ...' if len(keys) > 3 else ''}"
                           for what, keys in (("missing", missing), ("unknown", unknown), ("wrong shape", wrong))
                           if keys)
        raise PegasusError(f"{path}: its weights do not fit its model_config ({detail})")
    return config


def model_from_checkpoint(state: dict) -> DopeNetwork:
    """The trained network of a checkpoint (as ``load_checkpoint`` returns it), in eval mode on the CPU."""
    model = build_model(state["model_config"])
    model.load_state_dict(state["model"])
    return model.eval()

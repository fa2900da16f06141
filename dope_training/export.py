"""ONNX export of a DOPE network, and its parity with torch under onnxruntime.

The graph's input ``image`` [B, 3, H, W] float32 is RGB in 0..1 (H, W multiples of 8): the normalisation
(mean/std, stored in the model's config) is part of the network and so of the graph. Its outputs are the
last stage's ``beliefs`` [B, K + 1, H/8, W/8] and ``affinities`` [B, 2 K, H/8, W/8] (K = the config's
``keypoints``, DOPE's 8), and for a network with a
distance head ``distance`` [B, 1, H/8, W/8] (distance codes, ``targets.distance_code``); batch, height and width
are dynamic. metadata_props hold ``variant``, ``stride``, ``input`` (the layout and range above),
``mean``, ``std`` (JSON lists) and ``config`` (the model's config as JSON, for ``model.build_model``); an
export from a training checkpoint adds ``object`` (the TargetObject as JSON: obj_id, name, model box in
metres, symmetric), ``input_short_side`` and ``input_focal_px`` (px: the scale the network was trained
at, ``data.input_scale``, which inference reproduces).
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import onnx
import onnxruntime
import torch
from torch import nn

from dope_training.checkpoint import load_checkpoint, model_from_checkpoint
from dope_training.model import DopeNetwork, model_config
from dope_training.targets import STRIDE
from pegasus_gen.errors import PegasusError
from pegasus_gen.io.files import give_default_mode

INPUT = "RGB float32 0..1, [B, 3, H, W], H and W multiples of 8"


@contextmanager
def _evaluating(model: nn.Module):
    """Eval mode without gradients for the block, then the model's former mode."""
    was_training = model.training
    model.eval()
    try:
        with torch.no_grad():
            yield
    finally:
        model.train(was_training)


class _LastStage(nn.Module):
    """The network with only its last stage's (beliefs, affinities[, distance]) as outputs."""

    def __init__(self, model: DopeNetwork):
        super().__init__()
        self.model = model

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, ...]:
        return self.model(image)[-1]


def export_onnx(model: DopeNetwork, path: str | Path, opset: int = 17, metadata: dict[str, str] | None = None) -> Path:
    """Write ``model`` as an ONNX file at ``path`` (via a temporary file in the same folder, renamed when
    complete and checked) with ``metadata`` added to the standard keys; returns the path. A network whose
    outputs are not finite (NaN or inf weights) is refused before anything is written."""
    path = Path(path)
    with _evaluating(model):
        outputs = model(torch.zeros(1, 3, 64, 64))[-1]
    if not all(torch.isfinite(t).all() for t in outputs):
        raise PegasusError(f"{path}: not written: the network's outputs are not finite (NaN or inf weights: was its "
                           "training loss finite?)")
    config = model_config(model)
    maps = {0: "batch", 2: "map_height", 3: "map_width"}
    names = ["beliefs", "affinities", "distance"][:len(outputs)]
    fd, tmp = tempfile.mkstemp(suffix=".onnx.tmp", dir=path.parent)
    os.close(fd)
    try:
        with _evaluating(model), warnings.catch_warnings():
            # TorchScript exporter (its deprecation notice silenced): the torch.export one needs onnxscript
            warnings.filterwarnings("ignore", category=DeprecationWarning)
            torch.onnx.export(_LastStage(model), torch.zeros(1, 3, 64, 64), tmp, dynamo=False, opset_version=opset,
                              input_names=["image"], output_names=names,
                              dynamic_axes={"image": {0: "batch", 2: "height", 3: "width"},
                                            **{name: maps for name in names}})
        graph = onnx.load(tmp)
        meta = {"variant": config["variant"], "stride": str(STRIDE), "input": INPUT,
                "mean": json.dumps(list(config["mean"])), "std": json.dumps(list(config["std"])),
                "config": json.dumps(config), **(metadata or {})}
        for key, value in meta.items():
            graph.metadata_props.add(key=key, value=value)
        onnx.checker.check_model(graph)
        onnx.save(graph, tmp)
        give_default_mode(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def check_parity(model: DopeNetwork, path: str | Path, sizes, seed: int = 0) -> float:
    """Max abs difference between onnxruntime (CPU) on the file at ``path`` and torch on ``model``, over all its
    outputs, for random inputs of each (batch, height, width) in ``sizes``; inf when either gives a value that is
    not finite."""
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(seed)
    worst = 0.0
    for batch, height, width in sizes:
        image = rng.random((batch, 3, height, width), dtype=np.float32)
        with _evaluating(model):
            expected = [t.numpy() for t in model(torch.from_numpy(image))[-1]]
        got = session.run(None, {"image": image})
        if not all(np.isfinite(a).all() for a in (*got, *expected)):
            return math.inf
        worst = max(worst, *(float(np.abs(g - e).max()) for g, e in zip(got, expected)))
    return worst


def export_checkpoint(checkpoint: str | Path, path: str | Path, opset: int = 17,
                      tolerance: float = 1e-4) -> tuple[Path, float]:
    """Export a training checkpoint's network with its object and input scale as metadata, then check
    onnxruntime against torch at two sizes; a file whose outputs differ by more than ``tolerance`` (or are not
    finite) is removed and reported. Returns (path, max abs difference)."""
    state = load_checkpoint(checkpoint)
    model = model_from_checkpoint(state)
    metadata = {"object": json.dumps(state["object"]), "input_short_side": str(state["train_config"]["size"]),
                "input_focal_px": str(state["train_config"].get("focal_px", 0.0))}
    path = export_onnx(model, path, opset, metadata)
    diff = check_parity(model, path, [(1, 240, 320), (2, 64, 96)])
    if diff > tolerance:
        path.unlink()
        problem = "onnxruntime or torch gives outputs that are not finite" if math.isinf(diff) else \
            f"onnxruntime differs from torch by {diff:.2e} > {tolerance:g}"
        raise PegasusError(f"{path}: {problem}; not kept")
    return path, diff

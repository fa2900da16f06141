"""Checkpoints are read as data only: the project's own load, a crafted one cannot run code."""

import os
from dataclasses import asdict

import pytest
import torch

from dope_training.checkpoint import CHECKPOINT_FORMAT, TargetObject, load_checkpoint, model_from_checkpoint
from dope_training.model import ModelConfig, build_model, model_config
from pegasus_gen.cli.main import main
from pegasus_gen.errors import PegasusError


class Payload:
    """Unpickling this calls os.mkdir(marker): code run from a data file."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return os.mkdir, (self.marker,)


def test_a_checkpoint_that_would_run_code_is_refused_without_running_it(tmp_path, capsys):
    marker = tmp_path / "code_ran"
    model = build_model(ModelConfig.of("light"))
    crafted = {"format": CHECKPOINT_FORMAT, "model": model.state_dict(), "optimizer": {}, "scaler": {}, "epoch": 1,
               "step": 1, "model_config": model_config(model), "train_config": {"size": 64}, "stride": 8,
               "object": asdict(TargetObject(1, "cup", [-0.05] * 3, [0.1] * 3)), "payload": Payload(marker)}
    torch.save(crafted, tmp_path / "crafted.pt")
    with pytest.raises(PegasusError, match="not a readable checkpoint"):
        load_checkpoint(tmp_path / "crafted.pt")
    assert not marker.exists()
    assert main(["export", str(tmp_path / "crafted.pt"), "--out", str(tmp_path / "m.onnx")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "crafted.pt: not a readable checkpoint" in err[0]
    assert not marker.exists() and not (tmp_path / "m.onnx").exists()

    # the same checkpoint without the payload is the project's kind and loads
    del crafted["payload"]
    torch.save(crafted, tmp_path / "plain.pt")
    loaded = model_from_checkpoint(load_checkpoint(tmp_path / "plain.pt"))
    assert all(torch.equal(a, b) for a, b in zip(loaded.state_dict().values(), model.state_dict().values()))

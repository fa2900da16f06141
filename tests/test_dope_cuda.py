"""DOPE on CUDA (runs only where torch sees a GPU): AMP training steps, a checkpoint that loads on the CPU
and maps that agree with the CPU within half precision's reach."""

import numpy as np
import pytest
import torch

from dope_training.checkpoint import load_checkpoint, model_from_checkpoint
from dope_training.data import Augment, DopeDataset
from dope_training.train import TrainConfig, load_training_samples, train

pytestmark = [pytest.mark.gpu, pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")]


def test_amp_training_on_cuda_learns_and_its_checkpoint_runs_on_the_cpu(dope_dataset, tmp_path):
    cfg = TrainConfig(data=[str(dope_dataset)], object="noodle_cup_red", out=str(tmp_path / "run"), size=160,
                      batch_size=4, epochs=60, augment=False, loader_workers=0, device="cuda", checkpoint_every=60)
    run = train(cfg)
    state = load_checkpoint(run / "last.pt")
    assert state["scaler"] and state["epoch"] == 60
    model = model_from_checkpoint(state)
    image = DopeDataset(load_training_samples(cfg)[0][:1], 160, Augment(enabled=False))[0][0][None]
    with torch.no_grad():
        cpu = model(image)[-1][0].numpy()
        gpu = model.cuda()(image.cuda())[-1][0].cpu().numpy()
    assert np.isfinite(cpu).all() and np.abs(cpu - gpu).max() < 1e-2


def test_inference_on_cuda_in_half_precision_matches_the_cpu():
    """``DopeModel``'s CUDA path (half precision, channels-last) gives the CPU's float32 maps within half
    precision's reach."""
    from dope_training.infer import inference_network, network_outputs
    from dope_training.model import DopeNetwork, ModelConfig

    torch.manual_seed(0)
    model = DopeNetwork(ModelConfig.of("light")).eval()
    x = np.random.default_rng(0).random((1, 3, 240, 320), dtype=np.float32)
    cpu = network_outputs(inference_network(model, torch.device("cpu")), x)
    gpu = network_outputs(inference_network(model, torch.device("cuda")), x)
    assert [a.shape for a in gpu] == [a.shape for a in cpu]
    for a, b in zip(cpu, gpu):
        scale = float(np.abs(a).max())
        assert b.dtype == np.float32 and scale > 0 and np.abs(a - b).max() < 0.02 * scale, np.abs(a - b).max() / scale

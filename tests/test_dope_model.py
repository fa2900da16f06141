"""The DOPE network: stride-8 outputs of both variants, the original's size, VGG19 weights loading by
torchvision's layout, the loss, the distance head, a light model that learns, and the device a name asks for."""

import numpy as np
import pytest
import torch

from dope_training.model import (
    DISTANCE_HUBER,
    DISTANCE_LOSS_WEIGHT,
    DopeNetwork,
    ModelConfig,
    build_model,
    dope_loss,
    load_vgg19_weights,
    model_config,
    torch_device,
)
from pegasus_gen.errors import PegasusError


def test_outputs_are_stride_8_with_9_beliefs_and_16_affinities():
    for variant, stages in (("full", 6), ("light", 3)):
        model = DopeNetwork(ModelConfig.of(variant)).eval()
        with torch.no_grad():
            outputs = model(torch.rand(2, 3, 64, 96))
        assert len(outputs) == stages
        assert all(tuple(b.shape) == (2, 9, 8, 12) and tuple(a.shape) == (2, 16, 8, 12) for b, a in outputs)


def test_full_model_has_the_original_size_and_rebuilds_from_its_config():
    model = DopeNetwork(ModelConfig.of("full"))
    params = sum(p.numel() for p in model.parameters())
    # VGG19 to conv4_2: 7.6M; each 7x7 stage: ~4M per branch; stage 1 ~0.6M per branch -> ~51M in all
    assert 45e6 < params < 56e6, params
    light = build_model(model_config(DopeNetwork(ModelConfig.of("light"))))
    assert sum(p.numel() for p in light.parameters()) < params / 20


def test_vgg19_weights_load_from_a_torchvision_style_state_dict(tmp_path):
    model = DopeNetwork(ModelConfig.of("full"))
    donor = DopeNetwork(ModelConfig.of("full"))
    state = {f"features.{k}": v for k, v in donor.features.state_dict().items()}
    state["features.25.weight"] = torch.zeros(512, 512, 3, 3)  # conv4_3 and beyond: not part of DOPE
    state["classifier.0.weight"] = torch.zeros(4096, 25088)
    torch.save(state, tmp_path / "vgg19-dcbb9e9d.pth")
    assert load_vgg19_weights(model, tmp_path / "vgg19-dcbb9e9d.pth")
    for a, b in zip(model.features.parameters(), donor.features.parameters()):
        assert torch.equal(a, b)
    assert not load_vgg19_weights(model, tmp_path / "absent.pth")


def test_loss_is_zero_only_for_perfect_outputs_and_the_light_model_learns():
    torch.manual_seed(0)
    beliefs, affinities = torch.rand(2, 9, 8, 8), torch.rand(2, 16, 8, 8) * 2 - 1
    assert dope_loss([(beliefs, affinities)] * 3, beliefs, affinities).item() == 0.0
    from dope_training.targets import make_targets

    kp = np.random.default_rng(0).uniform(8, 56, (2, 1, 9, 2))
    targets = [make_targets(k, np.ones((1, 9), bool), 64, 64) for k in kp]
    beliefs = torch.from_numpy(np.stack([t[0] for t in targets]))
    affinities = torch.from_numpy(np.stack([t[1] for t in targets]))
    model = DopeNetwork(ModelConfig.of("light"))
    images = torch.rand(2, 3, 64, 64)
    optimiser = torch.optim.Adam(model.parameters(), 1e-3)
    losses = []
    for _ in range(80):
        loss = dope_loss(model(images), beliefs, affinities)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(loss.item())
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:5])


def test_a_distance_head_adds_one_map_to_the_last_stage_and_its_loss_counts_only_where_weighted():
    from dataclasses import replace

    for variant in ("light", "pretrained"):
        model = DopeNetwork(replace(ModelConfig.of(variant), distance_head=True)).eval()
        with torch.no_grad():
            outputs = model(torch.rand(2, 3, 64, 96))
        assert [len(o) for o in outputs] == [2, 2, 3] and tuple(outputs[-1][2].shape) == (2, 1, 8, 12)
        assert build_model(model_config(model)).distance is not None
    assert DopeNetwork(ModelConfig.of("light")).distance is None

    torch.manual_seed(0)
    beliefs, affinities = torch.rand(2, 9, 8, 8), torch.rand(2, 16, 8, 8) * 2 - 1
    codes, weight = torch.rand(2, 1, 8, 8), torch.zeros(2, 1, 8, 8)
    weight[0, 0, 3, 4] = 1.0
    off = codes.clone()
    off[weight == 0] += 5.0  # wrong only where nothing is weighted: no loss
    assert dope_loss([(beliefs, affinities, off)], beliefs, affinities, 0.0, codes, weight).item() == 0.0
    off[0, 0, 3, 4] += 1.0  # 1.0 off in log distance at the weighted cell: Huber 1 - 0.05 / 2, times the weight
    loss = dope_loss([(beliefs, affinities, off)], beliefs, affinities, 0.0, codes, weight).item()
    assert loss == pytest.approx(DISTANCE_LOSS_WEIGHT * (1.0 - DISTANCE_HUBER / 2))


def test_the_distance_head_learns_the_codes_at_the_centroids():
    from dataclasses import replace

    from dope_training.targets import make_distance_targets, make_targets

    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    kp = rng.uniform(8, 56, (2, 1, 9, 2))
    codes = rng.uniform(-1, 1, 2)  # one instance per image, each at its own distance
    targets = [make_targets(k, np.ones((1, 9), bool), 64, 64) for k in kp]
    distance = [make_distance_targets(k[:, 8], [c], 64, 64) for k, c in zip(kp, codes)]
    beliefs, affinities, codes_t, weight = (torch.from_numpy(np.stack([t[i] for t in group]))
                                            for group, i in ((targets, 0), (targets, 1), (distance, 0), (distance, 1)))
    model = DopeNetwork(replace(ModelConfig.of("light"), distance_head=True))
    images = torch.rand(2, 3, 64, 64)
    optimiser = torch.optim.Adam(model.parameters(), 1e-3)
    errors = []
    for _ in range(80):
        outputs = model(images)
        loss = dope_loss(outputs, beliefs, affinities, 0.0, codes_t, weight)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        errors.append(float(((outputs[-1][2] - codes_t).abs() * weight).sum() / weight.sum()))
    assert np.mean(errors[-5:]) < 0.3 * np.mean(errors[:5]), (errors[:5], errors[-5:])


def test_the_distance_heads_loss_leaves_the_rest_of_the_network_as_it_is():
    """The head reads the network detached: with and without the distance term the trunk's and stages'
    gradients are the same, and the head's own parameters get a gradient only from it."""
    from dataclasses import replace

    torch.manual_seed(0)
    model = DopeNetwork(replace(ModelConfig.of("light"), distance_head=True))
    images, beliefs, affinities = torch.rand(2, 3, 64, 64), torch.rand(2, 9, 8, 8), torch.rand(2, 16, 8, 8)
    codes, weight = torch.rand(2, 1, 8, 8) + 3.0, torch.rand(2, 1, 8, 8)

    def gradients(with_distance: bool) -> dict[str, torch.Tensor]:
        model.zero_grad()
        outputs = model(images)
        loss = dope_loss(outputs, beliefs, affinities, 0.0, codes if with_distance else None, weight)
        loss.backward()
        return {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}

    with_head, without = gradients(True), gradients(False)
    head = {n for n in with_head if n.startswith("distance.")}
    assert head and not head & without.keys() and any(with_head[n].abs().sum() > 0 for n in head)
    assert without.keys() == with_head.keys() - head
    for name, grad in without.items():
        torch.testing.assert_close(with_head[name], grad, rtol=0, atol=0)


def test_a_share_of_the_distance_heads_gradient_reaches_the_trunk_and_stages_in_proportion():
    """With ``distance_grad`` g the gradient of the distance codes on every trunk and stage parameter is g times
    the one it has with the head fully attached (g = 1), the head's own gradient is the same for every g, and
    the codes do not depend on g."""
    from dataclasses import replace

    torch.manual_seed(0)
    model = DopeNetwork(replace(ModelConfig.of("light"), distance_head=True)).double()
    images, weight = torch.rand(2, 3, 64, 64, dtype=torch.float64), torch.rand(2, 1, 8, 8, dtype=torch.float64)

    def gradients(share: float) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        model.zero_grad()
        codes = model(images, distance_grad=share)[-1][2]
        (codes * weight).sum().backward()
        return {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}, codes.detach()

    (full, codes_full), (share, codes_share) = gradients(1.0), gradients(0.25)
    torch.testing.assert_close(codes_share, codes_full, rtol=0, atol=0)
    rest = [n for n in full if not n.startswith("distance.")]
    assert full.keys() == share.keys() and rest and all(full[n].abs().sum() > 0 for n in rest)
    for name in full:
        expected = full[name] if name.startswith("distance.") else 0.25 * full[name]
        torch.testing.assert_close(share[name], expected, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("cuda", [False, True])
def test_the_device_a_name_asks_for_and_cuda_refused_where_torch_sees_none(monkeypatch, cuda):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: cuda)
    assert torch_device("cpu") == torch.device("cpu")
    assert torch_device("auto", 1) == (torch.device("cuda", 1) if cuda else torch.device("cpu"))
    if cuda:
        assert torch_device("cuda", 2) == torch.device("cuda", 2)
    else:
        with pytest.raises(PegasusError, match="--device cuda asked for, but torch sees no CUDA device"):
            torch_device("cuda")

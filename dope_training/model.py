"""The DOPE network (Tremblay et al. 2018) and a light variant for CPU training.

``full``: VGG19 conv1_1..conv4_2 (stride 8) laid out like torchvision's ``vgg19().features[:23]`` so its
ImageNet weights load, then 512->256->128 3x3 convs; six stages, each with a belief branch (9 maps) and
an affinity branch (16 maps); stage 1 from the features (three 3x3 convs, 1x1 to 512, 1x1 out), stages
2-6 from concat(beliefs, affinities, features) = 153 channels (five 7x7 convs, 1x1, 1x1 out). The maps are
DOPE's for 8 object points and the centre; with ``keypoints`` K points, K + 1 belief and 2 K affinity maps.
``light``: the same structure at a quarter of the trunk width, 64-channel stages with 3x3 instead of
7x7 kernels, 3 stages and BatchNorm after every hidden convolution (it trains from scratch: without
normalisation the deep plain stack sits at all-zero or blurred beliefs for thousands of steps); about 60x
fewer multiply-adds, so it trains on a laptop CPU in minutes. ``pretrained``: the light variant's stages on
the ImageNet-pretrained EfficientNet-Lite0 trunk (``dope_training.backbone``: stride 8, 152 channels), whose
features were learnt on real photos. Normalisation (the trunk's mean/std) happens inside the network: its
input is RGB in 0..1.

With ``distance_head`` a last branch reads the last stage's input (its beliefs, affinities and the features) and
gives one map: at each centroid the object's distance code (``targets.distance_code``: how far away it is, from
how large it looks), so that the distance need not come from the spread of the corners alone (on real photos
the corners found span too small a cuboid, and PnP puts the object too far away). The branch reads its input
detached: its loss trains the branch alone and leaves the trunk and the stages as a network without it would
learn them (attached, it pulled them towards distance and away from the corners: the cat's rotation on its own
generated frames went from 13 to 57 degrees, docs/TRAINING.md run L). ``forward``'s ``distance_grad`` lets a share of
the head's gradient back into them (training only; the outputs are the same). With ``distance_off_axis`` the
code is of the depth at which the object would look as large on the optical axis (``targets.off_axis_factor``).
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from torch import nn

from dope_training.backbone import OUT_CHANNELS as LITE0_CHANNELS
from dope_training.backbone import LiteTrunk
from dope_training.targets import MIN_KEYPOINTS
from pegasus_gen.errors import PegasusError

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
LITE0_MEAN, LITE0_STD = (0.5, 0.5, 0.5), (0.5, 0.5, 0.5)  # EfficientNet-Lite's input scaling: -1..1
# the distance codes' share of the loss (a 10 % distance error then costs about what a stage's belief error does
# late in training) and the Huber loss's quadratic zone (log distance)
DISTANCE_LOSS_WEIGHT = 0.1
DISTANCE_HUBER = 0.05
VGG19_TO_CONV4_2 = (64, 64, "M", 128, 128, "M", 256, 256, 256, 256, "M", 512, 512)  # features[:23]


@dataclass
class ModelConfig:
    """Everything needed to rebuild a network; stored in checkpoints and ONNX metadata."""

    variant: str = "full"
    trunk: str = "vgg"  # vgg: VGG19 to conv4_2 (width / width_divisor); lite0: EfficientNet-Lite0 (backbone)
    stages: int = 6
    width_divisor: int = 1  # trunk channels = VGG's / this
    stage_channels: int = 128
    late_kernel: int = 7  # kernel of stages 2..n
    batch_norm: bool = False  # BatchNorm after every hidden conv (trains from scratch; the full trunk has none)
    mean: tuple[float, float, float] = IMAGENET_MEAN
    std: tuple[float, float, float] = IMAGENET_STD
    distance_head: bool = False  # a branch after the last stage giving distance codes (module docstring)
    distance_off_axis: bool = False  # its codes are of the depth on the optical axis that looks alike
    # (``targets.off_axis_factor``); False: of the depth itself, as networks trained before it
    keypoints: int = 8  # object points besides the centre: K + 1 belief maps, 2 K affinity maps

    @staticmethod
    def of(variant: str) -> "ModelConfig":
        if variant == "full":
            return ModelConfig()
        if variant in ("light", "pretrained"):
            trunk = {"trunk": "lite0", "mean": LITE0_MEAN, "std": LITE0_STD} if variant == "pretrained" else {}
            return ModelConfig(variant=variant, stages=3, width_divisor=4, stage_channels=64, late_kernel=3,
                               batch_norm=True, **trunk)
        raise ValueError(f"unknown DOPE variant {variant!r} (full, light or pretrained)")


def _conv(cin: int, cout: int, k: int, relu: bool = True, bn: bool = False) -> list[nn.Module]:
    """A k x k convolution (same padding), then BatchNorm (``bn``) and ReLU (``relu``; both only on hidden
    layers)."""
    layers = [nn.Conv2d(cin, cout, k, padding=k // 2, bias=not bn)]
    return layers + ([nn.BatchNorm2d(cout)] if bn else []) + ([nn.ReLU(inplace=True)] if relu else [])


def _branch(cin: int, cout: int, channels: int, first: bool, late_kernel: int, bn: bool) -> nn.Sequential:
    if first:
        layers = _conv(cin, channels, 3, bn=bn)
        for _ in range(2):
            layers += _conv(channels, channels, 3, bn=bn)
        layers += _conv(channels, 4 * channels, 1, bn=bn) + _conv(4 * channels, cout, 1, relu=False)
    else:
        layers = _conv(cin, channels, late_kernel, bn=bn)
        for _ in range(4):
            layers += _conv(channels, channels, late_kernel, bn=bn)
        layers += _conv(channels, channels, 1, bn=bn) + _conv(channels, cout, 1, relu=False)
    return nn.Sequential(*layers)


def _both(belief: nn.Module, affinity: nn.Module, x: torch.Tensor, streams: tuple | None):
    """(belief(x), affinity(x)), on ``streams`` (two CUDA streams) at once when given."""
    if streams is None:
        return belief(x), affinity(x)
    current = torch.cuda.current_stream()
    for stream in streams:  # both start once x is ready, neither waits for the other
        stream.wait_stream(current)
    outputs = []
    for branch, stream in zip((belief, affinity), streams):
        with torch.cuda.stream(stream):
            outputs.append(branch(x))
    for out, stream in zip(outputs, streams):
        current.wait_stream(stream)
        out.record_stream(current)  # read on the current stream: its memory is not reused before that is done
    return tuple(outputs)


class DopeNetwork(nn.Module):
    """image [B, 3, H, W] RGB 0..1 (H, W multiples of 8) -> list over stages of
    (beliefs [B, K + 1, H/8, W/8], affinities [B, 2 K, H/8, W/8]), K = ``config.keypoints`` (DOPE's 8: 9 and 16
    maps); with ``distance_head`` the last stage's tuple has a third map, distance codes [B, 1, H/8, W/8]."""

    def __init__(self, config: ModelConfig | None = None):
        super().__init__()
        self.config = config or ModelConfig()
        c = self.config
        if c.trunk == "lite0":
            self.features, cin = LiteTrunk(), LITE0_CHANNELS
        elif c.trunk == "vgg":
            layers, cin = [], 3
            for v in VGG19_TO_CONV4_2:
                if v == "M":
                    layers.append(nn.MaxPool2d(2, 2))
                else:
                    layers += _conv(cin, v // c.width_divisor, 3, bn=c.batch_norm)
                    cin = v // c.width_divisor
            self.features = nn.Sequential(*layers)  # without BatchNorm: indices as torchvision's vgg19().features
        else:
            raise ValueError(f"unknown trunk {c.trunk!r} (vgg or lite0)")
        self.reduce = nn.Sequential(*_conv(cin, 256 // c.width_divisor, 3, bn=c.batch_norm),
                                    *_conv(256 // c.width_divisor, 128 // c.width_divisor, 3, bn=c.batch_norm))
        if c.keypoints < MIN_KEYPOINTS:
            raise ValueError(f"keypoints {c.keypoints} < {MIN_KEYPOINTS}")
        feat, maps = 128 // c.width_divisor, 3 * c.keypoints + 1
        self.beliefs, self.affinities = (
            nn.ModuleList([_branch(feat if s == 0 else feat + maps, out, c.stage_channels, s == 0, c.late_kernel,
                                   c.batch_norm) for s in range(c.stages)])
            for out in (c.keypoints + 1, 2 * c.keypoints))
        self.distance = _branch(feat + maps, 1, c.stage_channels, False, c.late_kernel, c.batch_norm) \
            if c.distance_head else None
        self.register_buffer("mean", torch.tensor(c.mean).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(c.std).view(1, 3, 1, 1), persistent=False)

    def forward(self, image: torch.Tensor, streams: tuple | None = None,
                distance_grad: float = 0.0) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """``streams``: two CUDA streams on which each stage's belief and affinity branches run at once (inference
        on a large GPU, which one branch's small convolutions leave mostly idle); None: one after the other.
        ``distance_grad``: the share (0..1) of the distance head's gradient that reaches the stages and the trunk
        (0: none, the head reads them detached)."""
        features = self.reduce(self.features((image - self.mean) / self.std))
        x, outputs = features, []
        for belief, affinity in zip(self.beliefs, self.affinities):
            b, a = _both(belief, affinity, x, streams)
            outputs.append((b, a))
            x = torch.cat([b, a, features], dim=1)
        if self.distance is not None:
            head_input = x.detach() if distance_grad == 0 else x.detach() + distance_grad * (x - x.detach())
            outputs[-1] = (*outputs[-1], self.distance(head_input))
        return outputs


def build_model(config: dict | ModelConfig) -> DopeNetwork:
    """A network from a ModelConfig or its dict (as stored in a checkpoint)."""
    return DopeNetwork(_from_dict(config) if isinstance(config, dict) else config)


def _from_dict(doc: dict) -> ModelConfig:
    return ModelConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in doc.items()})


def config_from_dict(doc, where: str) -> ModelConfig:
    """The ModelConfig of ``doc`` (its dict, as checkpoints and ONNX metadata store it), checked by building its
    network on torch's meta device (nothing allocated); a PegasusError naming ``where`` when it describes no
    DOPE network."""
    try:
        config = _from_dict(doc)
        with torch.device("meta"):
            DopeNetwork(config)
    except (TypeError, ValueError, AttributeError, ArithmeticError, RuntimeError) as exc:
        raise PegasusError(f"{where}: not a DOPE model config ({exc})") from None
    return config


def memory_estimate(config: ModelConfig, height: int, width: int, batch: int = 1, training: bool = False) -> int:
    """Bytes (float32) the network needs for ``batch`` images [3, height, width] (px): training keeps every
    layer's output for the backward pass and as many gradients (2 x their sum), and the weights with their
    gradients and Adam's two moments (4 x the weights); inference holds about a layer's input and output at
    once (2 x the largest output) and the weights. Layer outputs come from running the network on torch's meta
    device (shapes only, nothing allocated); in-place layers, which reuse their input, are not counted."""
    with torch.device("meta"):
        model = DopeNetwork(config).eval()
    outputs = []
    for module in model.modules():
        if not list(module.children()) and not getattr(module, "inplace", False):
            module.register_forward_hook(lambda _module, _inputs, output: outputs.append(output.numel()))
    with torch.no_grad():
        model(torch.empty(1, 3, height, width, device="meta"))
    weights = sum(p.numel() for p in model.parameters())
    floats = 2 * batch * sum(outputs) + 4 * weights if training else 2 * batch * max(outputs) + weights
    return 4 * floats


def torch_device(name: str, index: int = 0) -> torch.device:
    """The torch device of ``name`` ("auto", "cpu" or "cuda"; "auto": CUDA GPU ``index`` when torch sees one, else
    the CPU); a PegasusError for "cuda" where torch sees no CUDA device."""
    if name == "cuda" and not torch.cuda.is_available():
        raise PegasusError("--device cuda asked for, but torch sees no CUDA device")
    if name == "cuda" or (name == "auto" and torch.cuda.is_available()):
        return torch.device("cuda", index)
    return torch.device("cpu")


def memory_limit(device: torch.device) -> int:
    """Bytes of memory ``device`` has in all: the GPU's for CUDA, else the machine's RAM."""
    if device.type == "cuda":
        return torch.cuda.get_device_properties(device).total_memory
    return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def check_memory(needed: int, device: torch.device, what: str) -> None:
    """A PegasusError naming ``what`` when ``needed`` bytes exceed ``memory_limit(device)``."""
    limit = memory_limit(device)
    if needed > limit:
        raise PegasusError(f"{what} needs about {needed / 2**30:.3g} GiB of memory, more than the "
                           f"{limit / 2**30:.3g} GiB of this machine's {device.type.upper()}")


def model_config(model: DopeNetwork) -> dict:
    return asdict(model.config)


def vgg19_weights_path() -> Path | None:
    """torchvision's VGG19 checkpoint (``vgg19-*.pth``, the first by name) in the torch hub cache, if any."""
    return min((Path(torch.hub.get_dir()) / "checkpoints").glob("vgg19-*.pth"), default=None)


def load_vgg19_weights(model: DopeNetwork, path=None) -> bool:
    """Copy ImageNet VGG19 weights (torchvision's ``vgg19-*.pth`` state dict: ``features.N.weight/bias``) into
    the full model's trunk, from ``path`` or else from the torch hub cache; never downloads. Returns False
    when there is no such file."""
    if model.config.width_divisor != 1:
        raise ValueError(f"VGG19 weights fit only the full trunk, not the {model.config.variant!r} variant")
    path = Path(path) if path is not None else vgg19_weights_path()
    if path is None or not path.is_file():
        return False
    state = torch.load(path, map_location="cpu", weights_only=True)
    trunk = {k[len("features."):]: v for k, v in state.items()
             if k.startswith("features.") and int(k.split(".")[1]) < len(model.features)}
    model.features.load_state_dict(trunk)
    return True


def dope_loss(outputs, beliefs: torch.Tensor, affinities: torch.Tensor, peak_weight: float = 0.0,
              distance: torch.Tensor | None = None, distance_weight: torch.Tensor | None = None) -> torch.Tensor:
    """Sum over stages of MSE(beliefs) + MSE(affinities); targets [B, K + 1 | 2 K, h, w]. With ``peak_weight`` w > 0
    each belief cell's squared error is weighted by 1 + w * target (DOPE: 0), so the few cells near a
    keypoint are not drowned by the empty rest of the map. When the last stage has a distance map and
    ``distance`` targets [B, 1, h, w] are given, plus DISTANCE_LOSS_WEIGHT x the Huber error (DISTANCE_HUBER:
    its quadratic zone, in log distance) of the codes, averaged with ``distance_weight`` [B, 1, h, w]."""
    weight = 1.0 + peak_weight * beliefs
    loss = sum((weight * (b - beliefs) ** 2).mean() + nn.functional.mse_loss(a, affinities) for b, a, *_ in outputs)
    if len(outputs[-1]) == 3 and distance is not None:
        error = nn.functional.smooth_l1_loss(outputs[-1][2], distance, reduction="none", beta=DISTANCE_HUBER)
        loss = loss + DISTANCE_LOSS_WEIGHT * (distance_weight * error).sum() / distance_weight.sum().clamp(min=1.0)
    return loss

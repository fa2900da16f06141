"""The outline look: a zoomed second look at an estimate that reads where the object is, pixel by pixel, and fits the
model's outline to it.

The offsets look (``dope_training.zoom``) regresses one offset from the whole crop: on the photos its distance
spreads about twice as wide as on renders and reads some objects 1.5 % near (docs/TRAINING.md). The outline look
crops the image around the estimate as the zoom does (``zoom_window``: the object's diameter ``object_px`` long at the
estimated distance) and a small network (the ImageNet EfficientNet-Lite0 trunk and a decoder back to the crop's
pixels through its stride-8, -4 and -2 features) reads each crop pixel's probability of showing the object: where
the model at its true pose is seen, taught from the generated frames' poses and visible masks. The pose is then
fitted to that map as the refinement against the image fits it to the colours (``refine_rgb`` with the map as its
``probability``): every part of the outline counts, and a misread part is outvoted by the rest. ``LOOKS`` looks,
each from the pose the last fit gave; the fit moves the whole pose. The first look's fit also starts from the estimate
turned by ``START_TURNS_DEG`` either way about the camera's x and y axes, and keeps the fit whose silhouette agrees
best with the map (``map_agreement``): a fit from one start stops in the nearest minimum, often a turned one.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch
from torch import nn

from dope_training.backbone import BLOCKS, FINE, LiteTrunk, load_pretrained
from dope_training.refine_rgb import RgbRefineParams, refine_rgb
from dope_training.zoom import IMAGENET_MEAN, IMAGENET_STD, ZoomGeometry, in_front, moved, zoom_crop, zoom_window
from pegasus_gen.render.silhouette import mesh_coverage, mesh_silhouette

LOOKS = 2
# the fit to the map: the map's edges are clean, so the search starts 12 px wide and ends 3 px wide
FIT = RgbRefineParams(half_length_px=(12.0, 12.0, 6.0, 6.0, 6.0, 3.0, 3.0))
TARGET_SUPERSAMPLE = 4  # the true silhouette's coverage, 4 x 4 samples per crop pixel
START_TURNS_DEG = (15.0, 30.0)  # the first fit's further starts: the estimate turned so far about camera x and y


def _conv(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, 1, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class OutlineNet(nn.Module):
    """crops [B, 3, C, C] (0..1; C a multiple of 32) -> the object's logits [B, C, C]: the EfficientNet-Lite0
    trunk, then a decoder that joins its stride-16, -8, -4 and -2 features (upsampled, concatenated, 3 x 3
    convolutions) and whose stride-2 logits are bilinearly upsampled to the crop."""

    def __init__(self, pretrained: bool = True):
        super().__init__()
        self.trunk = LiteTrunk()
        if pretrained:
            load_pretrained(self.trunk)
        s2, s4, s8, s16 = BLOCKS[0][4], BLOCKS[2][4], BLOCKS[FINE - 1][4], BLOCKS[-1][4]
        self.up8, self.up4, self.up2 = _conv(s16 + s8, 64), _conv(64 + s4, 32), _conv(32 + s2, 16)
        self.logits = nn.Conv2d(16, 1, 1)
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        blocks = self.trunk.blocks
        s2 = blocks[0](self.trunk.stem((x - self.mean) / self.std))
        s4 = blocks[1:3](s2)
        s8 = blocks[3:FINE](s4)
        s16 = blocks[FINE:](s8)
        d = s16
        for fine, up in ((s8, self.up8), (s4, self.up4), (s2, self.up2)):
            d = nn.functional.interpolate(d, size=fine.shape[-2:], mode="bilinear", align_corners=False)
            d = up(torch.cat([d, fine], dim=1))
        return nn.functional.interpolate(self.logits(d), scale_factor=2, mode="bilinear", align_corners=False)[:, 0]


def crop_tensor(crops: np.ndarray) -> torch.Tensor:
    """crops [B, C, C, 3] uint8 -> the network's input [B, 3, C, C] float 0..1, laid out channels-last."""
    return torch.from_numpy(np.ascontiguousarray(crops)).permute(0, 3, 1, 2).float() / 255.0


def outline_target(T_true: np.ndarray, visible: np.ndarray, A: np.ndarray, K_crop: np.ndarray,
                   g: ZoomGeometry) -> np.ndarray:
    """[C, C] float32 0..1, what the network learns for one crop: the model's silhouette at its true pose T_true
    [4, 4] (m) seen with the crop's K_crop [3, 3] (antialiased coverage, exact to the mesh), where the instance's
    visible mask ``visible`` [H, W] (0/1, image px; grown by a pixel, since the mask's pixels are whole) warped
    into the crop by A [2, 3] says it is seen: the model's own outline where it shows, the occluder's where it is
    hidden."""
    grown = cv2.dilate(visible.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(np.float32)
    seen = cv2.warpAffine(grown, A, (g.crop_px, g.crop_px), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    cover = mesh_coverage(g.vertices, g.faces, K_crop, T_true, g.crop_px, g.crop_px, supersample=TARGET_SUPERSAMPLE)
    return np.minimum(cover, seen).astype(np.float32)


def turn_offset(axis: int, deg: float) -> np.ndarray:
    """``zoom.moved``'s offset [6] that turns a pose ``deg`` degrees about the camera's axis ``axis`` (0 x, 1 y,
    2 z) through the model box's centre, which stays where it was."""
    return np.r_[0.0, 0.0, 0.0, np.deg2rad(deg) * np.eye(3)[axis]]


def map_agreement(probability: np.ndarray, g: ZoomGeometry, K: np.ndarray, T: np.ndarray) -> float:
    """How well the model ``g`` at T [4, 4] agrees with ``probability`` [H, W] (0..1; K [3, 3]): the soft IoU
    sum(p s) / sum(p + s - p s) of the map p and the silhouette s (0/1), in [0, 1]; -1 when the model is not wholly
    in front of the camera (``in_front``)."""
    if not in_front(T, g):
        return -1.0
    height, width = probability.shape
    s = mesh_silhouette(g.vertices, g.faces, K, T, width, height).astype(np.float32)
    p = np.asarray(probability, np.float32)
    return float((p * s).sum() / max(float((p + s - p * s).sum()), 1e-6))


def fit_from_starts(image: np.ndarray, K: np.ndarray, T: np.ndarray, g: ZoomGeometry, probability: np.ndarray,
                    turns_deg: tuple[float, ...] = START_TURNS_DEG) -> np.ndarray:
    """T [4, 4] of the model ``g`` fitted to ``probability`` [H, W] (``refine_rgb``'s) in ``image`` (K [3, 3]) from T
    itself and from T turned +-each of ``turns_deg`` about the camera's x and y axes through the box centre
    (``turn_offset``): the fit with the best ``map_agreement``, the first on a tie."""
    starts = [T] + [moved(T, K, g, turn_offset(axis, sign * deg))
                    for axis in (0, 1) for sign in (-1, 1) for deg in turns_deg]
    fits = [refine_rgb(image, K, S, g.vertices, g.faces, FIT, probability=probability).T for S in starts]
    if len(fits) == 1:
        return fits[0]
    return fits[int(np.argmax([map_agreement(probability, g, K, F) for F in fits]))]


class OutlineRefiner:
    """A trained outline look for one object (``looks.load``) and its geometry: ``refine`` as ``ZoomRefiner``'s."""

    def __init__(self, net: OutlineNet, geometry: ZoomGeometry, obj_id: int, name: str, device: torch.device,
                 turns_deg: tuple[float, ...] = START_TURNS_DEG):
        self.net, self.geometry, self.obj_id, self.name, self.device = net.eval(), geometry, obj_id, name, device
        self.turns_deg = tuple(turns_deg)

    def probability(self, image: np.ndarray, K: np.ndarray, T: np.ndarray) -> np.ndarray:
        """[H, W] float32 0..1: the network's probability of the object in ``image`` [H, W, 3] uint8 RGB (K [3, 3])
        over the crop around the estimate T [4, 4] (``zoom_window``), 0 beyond it."""
        g = self.geometry
        w = zoom_window(T, K, g)
        with torch.no_grad():
            p = torch.sigmoid(self.net(crop_tensor(zoom_crop(image, w, g)[None]).to(self.device))).cpu().numpy()[0]
        height, width = image.shape[:2]
        return cv2.warpAffine(p, w.A, (width, height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)

    def refine(self, image: np.ndarray, K: np.ndarray, T: np.ndarray, iterations: int = LOOKS) -> np.ndarray:
        """T [4, 4] of an estimate in ``image`` [H, W, 3] uint8 RGB (an undistorted pinhole camera, K [3, 3]) fitted
        ``iterations`` times to the network's map of the object, the first time from several starts
        (``fit_from_starts`` with ``turns_deg``). A pose with part of the model at or behind the camera plane stays
        where it is."""
        g = self.geometry
        for look in range(iterations):
            if not in_front(T, g):
                break
            T = fit_from_starts(image, K, T, g, self.probability(image, K, T), self.turns_deg if look == 0 else ())
        return T


def outline_refiner(doc: dict, g: ZoomGeometry, device: torch.device) -> OutlineRefiner:
    """The OutlineRefiner of an outline look's checkpoint ``doc`` (``zoom.read_checkpoint``: its geometry ``g``) on
    ``device``."""
    net = OutlineNet(pretrained=False)
    net.load_state_dict(doc["model"])
    net = net.to(device, memory_format=torch.channels_last)  # as crop_tensor lays out its input
    return OutlineRefiner(net, g, int(doc["obj_id"]), str(doc["name"]), device)

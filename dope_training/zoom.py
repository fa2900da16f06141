"""The zoomed second look: a learned render-and-compare refinement of an estimate's position.

DOPE reads an object's distance from how large it looks in a stride-8 map on which the object spans 64 px: a
median 2-3 % off, where ADD's 0.1 d asks about 1 % (docs/TRAINING.md). For each estimate the image is cropped
around the estimate's projected centre (the model box's centre, DOPE's centroid keypoint) and scaled so that the
object's diameter spans ``object_px`` of a ``crop_px`` crop at the estimated distance; the model's silhouette at the
estimated pose is rendered into the same crop; a small network (the ImageNet EfficientNet-Lite0 trunk with a fourth
input channel for the silhouette, and a regression head) reads where the object in the image lies against that
silhouette: the centre's offset in the crop (in units of ``object_px``) and log(true / estimated distance), and a
network trained with ``rotation`` also the turn (a rotation vector in the camera frame, rad) that takes the estimated
rotation to the true one, about the box centre; without it the rotation is kept. ``ITERATIONS`` looks, each from the
pose the last one gave.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from scipy.spatial.transform import Rotation
from torch import nn

from dope_training.backbone import OUT_CHANNELS, STEM_CHANNELS, LiteTrunk, load_pretrained
from pegasus_gen.errors import PegasusError
from pegasus_gen.render.silhouette import mesh_coverage

ZOOM_FORMAT = "pegasus-zoom-1"
ITERATIONS = 2
# the spread of the offsets the network is taught (and the scale of its outputs): the centre's offset as a share of
# object_px, log(true / estimated distance), and the turn's rotation vector (rad; a turn of |N(0, 12 deg)| about a
# random axis has components of std 0.12 rad)
OFFSET_STD = np.array([0.04, 0.04, 0.04, 0.12, 0.12, 0.12], np.float32)
POSITION, WITH_ROTATION = 3, 6  # the network's outputs: the first three offsets, or all six
SUPERSAMPLE = 4  # the silhouette's antialiasing: coverage of 4 x 4 samples per crop pixel
INPUT_MEAN = (0.485, 0.456, 0.406, 0.5)  # ImageNet's for RGB, then the silhouette's coverage 0..1
INPUT_STD = (0.229, 0.224, 0.225, 0.5)


@dataclass(frozen=True)
class ZoomGeometry:
    """What the crop and the silhouette need of the object and the crop: its mesh (vertices [V, 3] m, model frame,
    faces [F, 3]; decimated), the model box's centre [3] (m, model frame), its diameter (m), the crop's size and the
    diameter's length in it (px)."""

    vertices: np.ndarray
    faces: np.ndarray
    centre: np.ndarray
    diameter: float
    crop_px: int
    object_px: float


@dataclass(frozen=True)
class ZoomWindow:
    """One estimate's crop: A [2, 3] image -> crop px, K [3, 3] of the crop's pixels, the estimate's centre in the
    camera frame [3] (m) and in the image [2] (px), and the scale s (crop px per image px)."""

    A: np.ndarray
    K: np.ndarray
    centre: np.ndarray
    centre_px: np.ndarray
    s: float


def zoom_window(T: np.ndarray, K: np.ndarray, g: ZoomGeometry) -> ZoomWindow:
    """The crop of the estimate T_cam_obj [4, 4] (m) in an image seen with K [3, 3]: centred on the projected box
    centre, the object's diameter ``g.object_px`` long at the centre's depth."""
    p = T[:3, :3] @ g.centre + T[:3, 3]
    uv = (K @ p)[:2] / p[2]
    s = g.object_px * p[2] / (g.diameter * K[0, 0])
    middle = (g.crop_px - 1) / 2
    A = np.array([[s, 0.0, middle - s * uv[0]], [0.0, s, middle - s * uv[1]]])
    return ZoomWindow(A, np.vstack([A, [0.0, 0.0, 1.0]]) @ K, p, uv, float(s))


def zoom_input(image: np.ndarray, T: np.ndarray, K: np.ndarray, g: ZoomGeometry) -> tuple[np.ndarray, np.ndarray,
                                                                                         ZoomWindow]:
    """The crop [C, C, 3] uint8 of ``image`` [H, W, 3] uint8 RGB around the estimate T [4, 4] (``zoom_window``),
    the model's silhouette at T in it [C, C] uint8 (coverage x 255, antialiased), and the window."""
    w = zoom_window(T, K, g)
    crop = cv2.warpAffine(image, w.A, (g.crop_px, g.crop_px), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    cover = mesh_coverage(g.vertices, g.faces, w.K, T, g.crop_px, g.crop_px, supersample=SUPERSAMPLE)
    return crop, np.rint(255 * cover).astype(np.uint8), w


def offsets(T_true: np.ndarray, T_est: np.ndarray, K: np.ndarray, g: ZoomGeometry) -> np.ndarray:
    """[6] what the network learns for the estimate T_est of an instance at T_true (both [4, 4], m): the true box
    centre's offset from the estimate's in the estimate's crop (x, y in units of ``g.object_px``), log(true /
    estimated depth of the centre), and the rotation vector [3] (camera frame, rad) of R_true R_est^T."""
    w = zoom_window(T_est, K, g)
    p = T_true[:3, :3] @ g.centre + T_true[:3, 3]
    uv = (K @ p)[:2] / p[2]
    turn = Rotation.from_matrix(T_true[:3, :3] @ T_est[:3, :3].T).as_rotvec()
    return np.array([*((uv - w.centre_px) * w.s / g.object_px), np.log(p[2] / w.centre[2]), *turn], np.float32)


def moved(T: np.ndarray, K: np.ndarray, g: ZoomGeometry, offset: np.ndarray) -> np.ndarray:
    """T [4, 4] with its box centre moved by ``offset`` (``offsets``' units): [3] keeps the rotation, [6] also turns
    it about the box centre."""
    w = zoom_window(T, K, g)
    uv = w.centre_px + np.asarray(offset[:2], np.float64) * g.object_px / w.s
    p = np.linalg.solve(K, [uv[0], uv[1], 1.0]) * w.centre[2] * np.exp(offset[2])
    out = T.copy()
    if len(offset) == WITH_ROTATION:
        out[:3, :3] = Rotation.from_rotvec(np.asarray(offset[3:], np.float64)).as_matrix() @ T[:3, :3]
    out[:3, 3] = p - out[:3, :3] @ g.centre
    return out


class ZoomNet(nn.Module):
    """crop and silhouette [B, 4, C, C] (0..1; C a multiple of 32) -> the first ``outputs`` offsets [B, outputs]
    (POSITION or WITH_ROTATION) in units of OFFSET_STD: the EfficientNet-Lite0 trunk (its stem widened to a fourth
    channel, which starts at zero weight) and two strided convolutions and two linear layers."""

    def __init__(self, crop_px: int, outputs: int = POSITION, pretrained: bool = True):
        super().__init__()
        if crop_px % 32:
            raise PegasusError(f"a zoom crop of {crop_px} px: a multiple of 32 px expected")
        if outputs not in (POSITION, WITH_ROTATION):
            raise PegasusError(f"a zoom network of {outputs} outputs: {POSITION} or {WITH_ROTATION} expected")
        self.outputs = outputs
        self.trunk = LiteTrunk()
        if pretrained:
            load_pretrained(self.trunk)
        rgb = self.trunk.stem[1]
        stem = nn.Conv2d(4, STEM_CHANNELS, rgb.kernel_size, rgb.stride, bias=False)
        with torch.no_grad():
            stem.weight.zero_()
            stem.weight[:, :3] = rgb.weight
        self.trunk.stem[1] = stem
        cells = crop_px // 32
        self.head = nn.Sequential(
            nn.Conv2d(OUT_CHANNELS, 128, 3, 2, 1, bias=False), nn.BatchNorm2d(128), nn.ReLU(inplace=True),
            nn.Conv2d(128, 64, 3, 2, 1, bias=False), nn.BatchNorm2d(64), nn.ReLU(inplace=True),
            nn.Flatten(), nn.Linear(64 * cells * cells, 256), nn.ReLU(inplace=True), nn.Linear(256, outputs))
        self.register_buffer("mean", torch.tensor(INPUT_MEAN).view(1, 4, 1, 1))
        self.register_buffer("std", torch.tensor(INPUT_STD).view(1, 4, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.trunk((x - self.mean) / self.std))


def zoom_tensor(crops: np.ndarray, silhouettes: np.ndarray) -> torch.Tensor:
    """crops [B, C, C, 3] and silhouettes [B, C, C] (uint8) -> the network's input [B, 4, C, C] float 0..1."""
    x = np.concatenate([crops, silhouettes[..., None]], axis=-1).transpose(0, 3, 1, 2)
    return torch.from_numpy(np.ascontiguousarray(x)).float() / 255.0


class ZoomRefiner:
    """A trained zoom network for one object (``load``) and its geometry."""

    def __init__(self, net: ZoomNet, geometry: ZoomGeometry, obj_id: int, name: str, device: torch.device):
        self.net, self.geometry, self.obj_id, self.name, self.device = net.eval(), geometry, obj_id, name, device

    def refine(self, image: np.ndarray, K: np.ndarray, T: np.ndarray, iterations: int = ITERATIONS) -> np.ndarray:
        """T [4, 4] of an estimate in ``image`` [H, W, 3] uint8 RGB (an undistorted pinhole camera, K [3, 3]) with
        its position (and with a WITH_ROTATION network its rotation; else the rotation kept) refined ``iterations``
        times. A pose with part of the model at or behind the camera plane has no crop: it stays where it is."""
        for _ in range(iterations):
            if ((self.geometry.vertices @ T[:3, :3].T)[:, 2] + T[2, 3]).min() <= 1e-3:
                break
            crop, silhouette, _ = zoom_input(image, T, K, self.geometry)
            with torch.no_grad():
                out = self.net(zoom_tensor(crop[None], silhouette[None]).to(self.device)).cpu().numpy()[0]
            T = moved(T, K, self.geometry, out * OFFSET_STD[:self.net.outputs])
        return T


def save(path: Path, net: ZoomNet, g: ZoomGeometry, obj_id: int, name: str, config: dict) -> None:
    """The zoom network's checkpoint (tensors and plain values only: read back with weights_only)."""
    torch.save({"format": ZOOM_FORMAT, "obj_id": obj_id, "name": name, "config": config,
                "vertices": torch.from_numpy(g.vertices), "faces": torch.from_numpy(g.faces),
                "centre": torch.from_numpy(g.centre), "diameter": g.diameter, "crop_px": g.crop_px,
                "object_px": g.object_px, "outputs": net.outputs, "model": net.state_dict()}, path)


def load(path: str | Path, device: str | torch.device = "cpu") -> ZoomRefiner:
    """The ZoomRefiner saved at ``path``; a PegasusError when it is not a zoom checkpoint (nothing in it is run)."""
    path, device = Path(path), torch.device(device)
    try:
        doc = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise PegasusError(f"{path}: no such zoom checkpoint") from None
    except Exception as exc:  # torch raises several types for a file that is not a checkpoint
        raise PegasusError(f"{path}: not a readable zoom checkpoint ({type(exc).__name__})") from None
    if not isinstance(doc, dict) or doc.get("format") != ZOOM_FORMAT:
        raise PegasusError(f"{path}: not a zoom checkpoint (pegasus train-zoom writes them)")
    g = ZoomGeometry(doc["vertices"].numpy().astype(np.float64), doc["faces"].numpy().astype(np.int64),
                     doc["centre"].numpy().astype(np.float64), float(doc["diameter"]), int(doc["crop_px"]),
                     float(doc["object_px"]))
    net = ZoomNet(g.crop_px, int(doc.get("outputs", POSITION)), pretrained=False)  # checkpoints before: position
    net.load_state_dict(doc["model"])
    return ZoomRefiner(net.to(device), g, int(doc["obj_id"]), str(doc["name"]), device)

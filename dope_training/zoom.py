"""The zoomed second look: a learned render-and-compare refinement of an estimate's position.

DOPE reads an object's distance from how large it looks in a stride-8 map on which the object spans 64 px: a
median 2-3 % off, where ADD's 0.1 d asks about 1 % (docs/TRAINING.md). For each estimate the image is cropped
around the estimate's projected centre (the model box's centre, DOPE's centroid keypoint) and scaled so that the
object's diameter spans ``object_px`` of a ``crop_px`` crop at the estimated distance; the model's silhouette at the
estimated pose is rendered into the same crop (and with the ``colour`` view the model's vertex colours too, shaded as
under a light at the camera: what the estimate shows, not only where; with the ``normals`` view the model's surface
normals in the camera frame instead, its shape without the scan's colours); a small network (the ImageNet
EfficientNet-Lite0 trunk with more input channels for the view, and a regression head) reads where the object in the
image lies against that view: the centre's offset in the crop (in units of ``object_px``) and log(true / estimated
distance), and a network trained with ``rotation`` also the turn (a rotation vector in the camera frame, rad) that
takes the estimated rotation to the true one, about the box centre; without it the rotation is kept. ``ITERATIONS``
looks, each from the pose the last one gave.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch
from scipy.spatial.transform import Rotation
from torch import nn

from dope_training.backbone import OUT_CHANNELS, STEM_CHANNELS, LiteTrunk, load_pretrained
from pegasus_gen.errors import PegasusError
from pegasus_gen.render.raycast import MeshRaycaster
from pegasus_gen.render.silhouette import mesh_coverage

ZOOM_FORMAT = "pegasus-zoom-1"
ITERATIONS = 2
# the spread of the offsets the network is taught (and the scale of its outputs): the centre's offset as a share of
# object_px, log(true / estimated distance), and the turn's rotation vector (rad; a turn of |N(0, 12 deg)| about a
# random axis has components of std 0.12 rad)
OFFSET_STD = np.array([0.04, 0.04, 0.04, 0.12, 0.12, 0.12], np.float32)
POSITION, WITH_ROTATION = 3, 6  # the network's outputs: the first three offsets, or all six
SUPERSAMPLE = 4  # the silhouette's antialiasing: coverage of 4 x 4 samples per crop pixel
SURFACE_SUPERSAMPLE = 2  # the SURFACE_VIEWS': 2 x 2 rays per crop pixel
# what is rendered at the estimate beside the crop, and its channels: the silhouette's coverage, then (``colour``)
# the model's vertex colours, shaded by how squarely each face looks at the camera (ambient 0.35) and times coverage,
# or (``normals``) the faces' unit normals in the camera frame as (n + 1) / 2, times coverage
VIEW_CHANNELS = {"silhouette": 1, "colour": 4, "normals": 4}
SURFACE_VIEWS = ("colour", "normals")  # the views that cast rays at the model's mesh
IMAGENET_MEAN, IMAGENET_STD = (0.485, 0.456, 0.406), (0.229, 0.224, 0.225)
AMBIENT = 0.35


@dataclass(frozen=True)
class ZoomGeometry:
    """What the crop and the view need of the object and the crop: its mesh (vertices [V, 3] m, model frame,
    faces [F, 3]; decimated), the model box's centre [3] (m, model frame), its diameter (m), the crop's size and the
    diameter's length in it (px); for the SURFACE_VIEWS a ray caster of the mesh, and for the ``colour`` view its
    vertex colours [V, 3] (0..1) (``surfaced``)."""

    vertices: np.ndarray
    faces: np.ndarray
    centre: np.ndarray
    diameter: float
    crop_px: int
    object_px: float
    colours: np.ndarray | None = None
    raycaster: MeshRaycaster | None = field(default=None, compare=False, repr=False)


def surfaced(g: ZoomGeometry, colours: np.ndarray | None = None) -> ZoomGeometry:
    """``g`` with the ray caster the SURFACE_VIEWS cast at its mesh, and with vertex colours [V, 3] (0..1, one per
    vertex of ``g.vertices``; the ``colour`` view's) when given."""
    import trimesh

    if colours is not None:
        colours = np.asarray(colours, np.float32)
        if colours.shape != (len(g.vertices), 3):
            raise PegasusError(f"{colours.shape} vertex colours for a mesh of {len(g.vertices)} vertices: [V, 3] "
                               "expected")
    mesh = trimesh.Trimesh(g.vertices, g.faces, process=False)
    return ZoomGeometry(g.vertices, g.faces, g.centre, g.diameter, g.crop_px, g.object_px, colours,
                        MeshRaycaster(mesh))


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


def zoom_crop(image: np.ndarray, w: ZoomWindow, g: ZoomGeometry) -> np.ndarray:
    """[C, C, 3] uint8: ``image`` [H, W, 3] uint8 RGB resampled into the window ``w`` (bilinear, borders
    replicated)."""
    return cv2.warpAffine(image, w.A, (g.crop_px, g.crop_px), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def in_front(T: np.ndarray, g: ZoomGeometry) -> bool:
    """Whether the whole model at T [4, 4] (m) lies in front of the camera plane (a millimetre or more): else an
    estimate has no crop."""
    return bool(((g.vertices @ T[:3, :3].T)[:, 2] + T[2, 3]).min() > 1e-3)


def zoom_input(image: np.ndarray, T: np.ndarray, K: np.ndarray, g: ZoomGeometry,
               view: str = "silhouette") -> tuple[np.ndarray, np.ndarray, ZoomWindow]:
    """The crop [C, C, 3] uint8 of ``image`` [H, W, 3] uint8 RGB around the estimate T [4, 4] (``zoom_window``),
    the model's ``view`` at T in it [C, C, VIEW_CHANNELS[view]] uint8 (the silhouette's coverage x 255,
    antialiased; then the ``colour`` view's shaded colours or the ``normals`` view's normals x 255), and the
    window."""
    if view not in VIEW_CHANNELS:
        raise PegasusError(f"a zoom view {view!r}: one of {', '.join(VIEW_CHANNELS)} expected")
    w = zoom_window(T, K, g)
    crop = zoom_crop(image, w, g)
    channels = [mesh_coverage(g.vertices, g.faces, w.K, T, g.crop_px, g.crop_px, supersample=SUPERSAMPLE)[..., None]]
    if view in SURFACE_VIEWS:
        channels.append(surface_view(g, w.K, T, view))
    return crop, np.rint(255 * np.concatenate(channels, axis=-1)).astype(np.uint8), w


def surface_view(g: ZoomGeometry, K: np.ndarray, T: np.ndarray, view: str) -> np.ndarray:
    """[C, C, 3] float32 0..1: the model at T [4, 4] seen with the crop's K [3, 3], black off the model:
    ``colour``, its vertex colours with each face shaded by AMBIENT + (1 - AMBIENT) |its normal's z in the camera| (a
    light at the camera); ``normals``, each face's unit normal n in the camera frame (turned towards the camera)
    as (n + 1) / 2; SURFACE_SUPERSAMPLE^2 rays per pixel averaged."""
    if g.raycaster is None or (view == "colour" and g.colours is None):
        raise PegasusError(f"the {view} view needs the model's ray caster"
                           + (" and vertex colours" if view == "colour" else "") + " (zoom.surfaced)")
    s, size = SURFACE_SUPERSAMPLE, g.crop_px
    K_fine = np.diag([s, s, 1.0]) @ K + np.array([[0, 0, (s - 1) / 2], [0, 0, (s - 1) / 2], [0, 0, 0]])
    face, weights = g.raycaster.surface(K_fine, T, size * s, size * s)
    tri = g.vertices[g.faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    in_camera = normals @ T[:3, :3].T
    # each face's normal turned towards the camera (a model's faces need not all wind alike)
    centres = tri.mean(axis=1) @ T[:3, :3].T + T[:3, 3]
    in_camera *= np.where((in_camera * centres).sum(axis=1) > 0, -1.0, 1.0)[:, None]
    hit = face >= 0
    fine = np.zeros((size * s, size * s, 3), np.float32)
    f = face[hit]
    if view == "normals":
        fine[hit] = (in_camera[f] + 1) / 2
    else:
        shade = (AMBIENT + (1 - AMBIENT) * np.abs(in_camera[:, 2])).astype(np.float32)
        fine[hit] = np.einsum("nk,nkc->nc", weights[hit], g.colours[g.faces[f]]) * shade[f, None]
    return fine.reshape(size, s, size, s, 3).mean(axis=(1, 3))


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
    """crop and view [B, 3 + VIEW_CHANNELS[view], C, C] (0..1; C a multiple of 32) -> the first ``outputs`` offsets
    [B, outputs] (POSITION or WITH_ROTATION) in units of OFFSET_STD: the EfficientNet-Lite0 trunk (its stem widened
    to the view's channels, which start at zero weight) and two strided convolutions and two linear layers."""

    def __init__(self, crop_px: int, outputs: int = POSITION, pretrained: bool = True, view: str = "silhouette"):
        super().__init__()
        if crop_px % 32:
            raise PegasusError(f"a zoom crop of {crop_px} px: a multiple of 32 px expected")
        if outputs not in (POSITION, WITH_ROTATION):
            raise PegasusError(f"a zoom network of {outputs} outputs: {POSITION} or {WITH_ROTATION} expected")
        if view not in VIEW_CHANNELS:
            raise PegasusError(f"a zoom view {view!r}: one of {', '.join(VIEW_CHANNELS)} expected")
        self.outputs, self.view = outputs, view
        self.trunk = LiteTrunk()
        if pretrained:
            load_pretrained(self.trunk)
        rgb = self.trunk.stem[1]
        channels = 3 + VIEW_CHANNELS[view]
        stem = nn.Conv2d(channels, STEM_CHANNELS, rgb.kernel_size, rgb.stride, bias=False)
        with torch.no_grad():
            stem.weight.zero_()
            stem.weight[:, :3] = rgb.weight
        self.trunk.stem[1] = stem
        cells = crop_px // 32
        self.head = nn.Sequential(
            nn.Conv2d(OUT_CHANNELS, 128, 3, 2, 1, bias=False), nn.BatchNorm2d(128), nn.ReLU(inplace=True),
            nn.Conv2d(128, 64, 3, 2, 1, bias=False), nn.BatchNorm2d(64), nn.ReLU(inplace=True),
            nn.Flatten(), nn.Linear(64 * cells * cells, 256), nn.ReLU(inplace=True), nn.Linear(256, outputs))
        # ImageNet's statistics for the crop and the colour view, coverage 0..1 and the normals' (n + 1) / 2 about 0.5
        surface = (IMAGENET_MEAN, IMAGENET_STD) if view == "colour" else ((0.5,) * 3, (0.5,) * 3)
        mean, std = (*IMAGENET_MEAN, 0.5, *surface[0]), (*IMAGENET_STD, 0.5, *surface[1])
        self.register_buffer("mean", torch.tensor(mean[:channels]).view(1, channels, 1, 1))
        self.register_buffer("std", torch.tensor(std[:channels]).view(1, channels, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.trunk((x - self.mean) / self.std))


def zoom_tensor(crops: np.ndarray, views: np.ndarray) -> torch.Tensor:
    """crops [B, C, C, 3] and views [B, C, C, V] (uint8) -> the network's input [B, 3 + V, C, C] float 0..1, laid out
    channels-last (as the arrays lie: oneDNN's convolutions then skip their layout conversions, 1.6x the zoom
    network's training step on the CPU, benchmarks/dope.py)."""
    x = np.concatenate([crops, views], axis=-1)
    return torch.from_numpy(x).permute(0, 3, 1, 2).float() / 255.0


class ZoomRefiner:
    """A trained zoom network for one object (``load``) and its geometry."""

    def __init__(self, net: ZoomNet, geometry: ZoomGeometry, obj_id: int, name: str, device: torch.device):
        self.net, self.geometry, self.obj_id, self.name, self.device = net.eval(), geometry, obj_id, name, device

    def refine(self, image: np.ndarray, K: np.ndarray, T: np.ndarray, iterations: int = ITERATIONS) -> np.ndarray:
        """T [4, 4] of an estimate in ``image`` [H, W, 3] uint8 RGB (an undistorted pinhole camera, K [3, 3]) with
        its position (and with a WITH_ROTATION network its rotation; else the rotation kept) refined ``iterations``
        times. A pose with part of the model at or behind the camera plane has no crop: it stays where it is."""
        for _ in range(iterations):
            if not in_front(T, self.geometry):
                break
            crop, view, _ = zoom_input(image, T, K, self.geometry, self.net.view)
            with torch.no_grad():
                out = self.net(zoom_tensor(crop[None], view[None]).to(self.device)).cpu().numpy()[0]
            T = moved(T, K, self.geometry, out * OFFSET_STD[:self.net.outputs])
        return T


def save(path: Path, net: nn.Module, g: ZoomGeometry, obj_id: int, name: str, config: dict) -> None:
    """The zoom network's checkpoint (tensors and plain values only: read back with weights_only): a ZoomNet's (the
    offsets look) or an OutlineNet's (``dope_training.outline``)."""
    look = {"look": "offsets", "outputs": net.outputs, "view": net.view} if isinstance(net, ZoomNet) else {
        "look": "outline"}
    torch.save({"format": ZOOM_FORMAT, "obj_id": obj_id, "name": name, "config": config,
                "vertices": torch.from_numpy(g.vertices), "faces": torch.from_numpy(g.faces),
                "centre": torch.from_numpy(g.centre), "diameter": g.diameter, "crop_px": g.crop_px,
                "object_px": g.object_px, **look, "model": net.state_dict(),
                **({} if g.colours is None else {"colours": torch.from_numpy(g.colours)})}, path)


def read_checkpoint(path: str | Path) -> tuple[dict, ZoomGeometry]:
    """The checkpoint at ``path`` of either look (``save``; read by ``looks.load``) and its object's geometry; a
    PegasusError when it is not a zoom checkpoint (nothing in it is run)."""
    path = Path(path)
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
    return doc, g


def offsets_refiner(doc: dict, g: ZoomGeometry, path: str | Path, device: torch.device) -> ZoomRefiner:
    """The ZoomRefiner of an offsets look's checkpoint ``doc`` (``read_checkpoint``: its geometry ``g``, read from
    ``path``) on ``device``."""
    if "colours" in doc or doc.get("view") in SURFACE_VIEWS:
        g = surfaced(g, doc["colours"].numpy() if "colours" in doc else None)
    # checkpoints from before the rotation and the colour view: position, silhouette
    net = ZoomNet(g.crop_px, int(doc.get("outputs", POSITION)), pretrained=False,
                  view=str(doc.get("view", "silhouette")))
    if net.view == "colour" and g.colours is None:
        raise PegasusError(f"{path}: a colour-view zoom checkpoint without the model's colours")
    net.load_state_dict(doc["model"])
    net = net.to(device, memory_format=torch.channels_last)  # as zoom_tensor lays out its input
    return ZoomRefiner(net, g, int(doc["obj_id"]), str(doc["name"]), device)

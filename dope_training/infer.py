"""Object poses from an image with a trained DOPE network: onnxruntime (CPU or CUDA provider) on an exported
ONNX file, or torch on a training checkpoint.

Steps: the image is scaled to the training crops' nominal scale (``data.input_scale``: its fx becomes
``input_focal_px``, or with DOPE's policy its shorter side ``input_short_side``), padded right/bottom to a
multiple of 8, run; belief peaks are grouped into instances by the affinities (``decode.find_keypoints``); the
keypoints are taken back to image pixels (pixel centres: x_image = (x_net + 0.5) / scale - 0.5, as cv2.resize
samples); PnP (``pnp.solve_pose_consensus``: the corners' candidate peaks that best support a pose, then SQPnP and
Levenberg-Marquardt, keypoints that do not fit the others dropped) with the camera K gives the pose; a network
with a distance head then moves it onto the ray through the detected centroid at the distance the head reads
there (``on_centroid_ray``). Missing corners do not drop a detection: any 5 of the keypoints (DOPE's 9, or the
network's object points and the centroid, which counts as one) are solved, see ``pnp``. With a depth image,
each pose is then refined against it (``refine.refine_multistart``), starting from the pose moved onto the ray
through the detected centroid at the depth seen there (``on_centroid_ray``). A centroid whose keypoints PnP
cannot solve (too few corners joined it, or they put the object behind the camera) is then not lost: its
refinement starts on the same ray with the object's own axes (the several-start refinement tries the other
rotations), and it is kept when the depth confirms it. With the object's mesh instead, each solved pose is
refined against the RGB image itself (``refine_rgb``: its silhouette fitted to the image's colour edges). With a
zoom network (``zoom``: a second, zoomed-in look at each estimate that moves its centre and distance), each solved
pose is moved by it first, before either refinement, and scored by its detection score times the share of its outline
that the image's colour edges confirm there (``refine_rgb.outline_support``: on LM-O's photos it halved the false
positives at the same recall, docs/TRAINING.md run AX).
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
import torch

from dope_training.checkpoint import TargetObject, load_checkpoint, model_from_checkpoint, target_object
from dope_training.data import input_scale
from dope_training.decode import find_keypoints
from dope_training.keypoints import object_keypoints
from dope_training.looks import ZoomChain
from dope_training.looks import load as load_zoom
from dope_training.model import check_memory, config_from_dict, memory_estimate, torch_device
from dope_training.pnp import solve_pose_consensus
from dope_training.refine import Refinement, refine_multistart
from dope_training.refine_rgb import RgbRefinement, outline_support, refine_rgb
from dope_training.targets import STRIDE, distance_from_code, mapped_focal, off_axis_factor, read_map
from pegasus_gen.errors import PegasusError

# a candidate peak supports a pose within this many network-input px of its reprojected corner (pnp's consensus)
CONSENSUS_TAU_PX = 3.0
NO_PNP_START = np.array([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1], [0, 0, 0, 1]])  # the object's axes, 1 m ahead


@dataclass
class ObjectPose:
    """One detected instance: T_cam_obj [4, 4] (metres, camera frame, OpenCV axes) from DOPE + PnP (None
    when PnP could not solve its keypoints: then kept only because depth refinement found it), its detection
    score (``decode.Detection.score``), keypoints [P, 2] in image pixels (NaN where not found), the mean
    reprojection error (px, NaN without PnP) and, when a depth image was given, the depth refinement
    (``refine.Refinement``), or when the object's mesh was, the refinement against the RGB image
    (``refine_rgb.RgbRefinement``); with zoomed looks, ``support``: the share of T's outline that the image's
    colour edges confirm (``refine_rgb.outline_support``). ``score`` ranks and thresholds it: the detection score,
    times ``support`` where there is one."""

    T: np.ndarray | None
    detection_score: float
    keypoints: np.ndarray
    reprojection_error: float
    refinement: Refinement | None = None
    rgb_refinement: RgbRefinement | None = None
    support: float | None = None

    @property
    def score(self) -> float:
        """The detection score times the outline's ``support`` where there is one (0..1)."""
        return self.detection_score * (1.0 if self.support is None else self.support)

    @property
    def refined(self) -> np.ndarray | None:
        """The refined T_cam_obj [4, 4] when depth refinement accepted it, else None."""
        return self.refinement.T if self.refinement is not None and self.refinement.accepted else None

    def to_json(self) -> dict:
        out = {"R": None if self.T is None else self.T[:3, :3].tolist(),
               "t_m": None if self.T is None else self.T[:3, 3].tolist(), "score": self.score,
               "detection_score": self.detection_score, "support": self.support,
               "keypoints_px": [None if np.isnan(p).any() else p.tolist() for p in self.keypoints],
               "reprojection_error_px": None if self.T is None else self.reprojection_error}
        if self.refinement is not None:
            r = self.refinement
            out["refined"] = {"accepted": r.accepted, "R": r.T[:3, :3].tolist(), "t_m": r.T[:3, 3].tolist(),
                              "fitness": r.fitness, "rmse_m": r.rmse_m, "reason": r.reason}
        if self.rgb_refinement is not None:
            r = self.rgb_refinement
            out["rgb_refined"] = {"R": r.T[:3, :3].tolist(), "t_m": r.T[:3, 3].tolist(), "support": r.support}
        return out


def rgb_refined(poses: list[ObjectPose], min_score: float = 0.0) -> list[ObjectPose]:
    """The poses that ``DopeModel.estimate`` refined against the RGB image, as poses of their own: T the refined
    T_cam_obj, scored by the detection score times the share of the outline the image supports there
    (``RgbRefinement.support``: on generated held-out frames the product separates right estimates from false
    ones better than either), best first, those under ``min_score`` left out."""
    out = [replace(p, T=p.rgb_refinement.T, support=p.rgb_refinement.support)
           for p in poses if p.rgb_refinement is not None]
    return sorted((p for p in out if p.score >= min_score), key=lambda p: -p.score)


def centroid_ray(centroid_px: np.ndarray, K: np.ndarray, dist: np.ndarray | None = None) -> np.ndarray:
    """[2] normalised image coordinates (x / z, y / z) of the ray through ``centroid_px`` [2] (image px)."""
    return cv2.undistortPoints(np.asarray(centroid_px, np.float64).reshape(1, 1, 2), K, dist).reshape(2)


def on_centroid_ray(T_cam_obj: np.ndarray, points: np.ndarray, centroid_px: np.ndarray, K: np.ndarray,
                    dist: np.ndarray | None = None, depth_m: np.ndarray | None = None,
                    z_m: float | None = None) -> np.ndarray:
    """T_cam_obj [4, 4] moved so that the object's centre (``points`` [P, 3]: the network's object points,
    m, object frame, the last its box's centre) lies on the ray through the detected centroid ``centroid_px``
    [2] (image px): DOPE's centroid is its surest keypoint, while PnP lets wrong corners drag the centre off
    it, and its distance with it. The centre keeps its z, or takes ``z_m`` (m: the distance head's), or with
    ``depth_m`` [H, W] (m, 0 = none) the median depth of the 9x9 px around the centroid plus half the points'
    depth along the optical axis at the PnP rotation (the surface seen there is the object's front: the start
    of depth refinement)."""
    ray = centroid_ray(centroid_px, K, dist)
    centre = T_cam_obj[:3, :3] @ points[-1] + T_cam_obj[:3, 3]
    z = centre[2] if z_m is None else z_m
    if depth_m is not None:
        u, v = np.round(np.asarray(centroid_px)).astype(int)
        window = depth_m[max(v - 4, 0):max(v + 5, 0), max(u - 4, 0):max(u + 5, 0)]
        window = window[np.isfinite(window) & (window > 0)]
        if window.size:
            offsets = (points[:-1] - points[-1]) @ T_cam_obj[2, :3]
            z = float(np.median(window)) + float(np.ptp(offsets)) / 2
    out = T_cam_obj.copy()
    out[:3, 3] += np.r_[ray * z, z] - centre
    return out


def _metadata(meta: dict[str, str], key: str, parse, path: Path):
    """``meta[key]`` (ONNX metadata) parsed by ``parse`` (json.loads, int, float); a PegasusError naming the file
    and the key when it does not parse."""
    try:
        return parse(meta[key])
    except ValueError:
        raise PegasusError(f"{path}: metadata {key}={meta[key][:60]!r} is not what `pegasus export` writes") from None


def inference_network(model: torch.nn.Module, device: torch.device) -> torch.nn.Module:
    """``model`` (a DopeNetwork) on ``device`` as inference runs it: on CUDA in half precision (the tensor cores)
    with channels-last activations and cuDNN's autotuner (the fastest convolution algorithms, found once per input
    size), and :func:`network_outputs` runs each stage's two branches on two streams at once; on the CPU in
    float32 as trained, channels-last too (oneDNN's convolutions skip their layout conversions: 1.5x)."""
    model = model.to(device, memory_format=torch.channels_last).eval()
    if device.type == "cuda":
        torch.backends.cudnn.benchmark = True
        model = model.half()
    return model


def network_outputs(model: torch.nn.Module, x: np.ndarray) -> list[np.ndarray]:
    """The last stage's outputs of an :func:`inference_network` for a network input ``x`` [1, 3, H, W] float32 in
    [0, 1] (H, W multiples of STRIDE), float32 on the host: beliefs [1, K + 1, H/8, W/8], affinities
    [1, 2 K, H/8, W/8] and, with a distance head, distance codes [1, 1, H/8, W/8]."""
    weight = next(model.parameters())
    with torch.inference_mode():
        image = torch.from_numpy(x).to(weight.device, weight.dtype, memory_format=torch.channels_last)
        streams = _branch_streams(weight.device) if weight.is_cuda else None
        return [t.float().cpu().numpy() for t in model(image, streams)[-1]]


@functools.lru_cache(maxsize=None)
def _branch_streams(device: torch.device) -> tuple:
    """Two CUDA streams of ``device`` for the stages' two branches (made once per device)."""
    return torch.cuda.Stream(device), torch.cuda.Stream(device)


class DopeModel:
    """A trained network ready for images. ``path``: an ``.onnx`` export (onnxruntime) or a ``.pt`` training
    checkpoint (torch); ``device``: cpu, cuda or auto; ``use_distance_head``: place each pose at its distance
    head's distance (networks that have one), else where PnP puts it; ``zoom``: a zoom network's checkpoint
    (``pegasus train-zoom``) for the same object, or several applied in turn (e.g. the offsets look, then the
    outline look), which then move every solved pose."""

    def __init__(self, path: str | Path, device: str = "cpu", use_distance_head: bool = True,
                 zoom: str | Path | list | None = None):
        path = Path(path)
        self.use_distance_head = use_distance_head
        if not path.is_file():
            raise PegasusError(f"{path}: no such model file")
        self.path = path
        self._sizes_checked = set()
        if path.suffix == ".onnx":
            self._init_onnx(path, device)
        else:
            self._init_torch(path, device)
        self.points = object_keypoints(self.object.keypoints, self.object.bbox_min, self.object.bbox_size)  # [P, 3] m
        obj = self.object  # surface samples for depth refinement, as arrays once (None: trained without a model)
        self.surface = None if obj.surface_points is None else (np.asarray(obj.surface_points, np.float64),
                                                                np.asarray(obj.surface_normals, np.float64))
        zooms = [] if zoom is None else [zoom] if isinstance(zoom, (str, Path)) else list(zoom)
        looks = [load_zoom(z, self.device) for z in zooms]
        for z, look in zip(zooms, looks):
            if look.obj_id != obj.obj_id:
                raise PegasusError(f"{z}: a zoom network for obj_id {look.obj_id} ({look.name}), the model {path} "
                                   f"finds obj_id {obj.obj_id} ({obj.name})")
        self.zoom: ZoomChain | None = ZoomChain(looks) if looks else None

    def _init_onnx(self, path: Path, device: str) -> None:
        import onnxruntime

        available = onnxruntime.get_available_providers()
        if device == "cuda" and "CUDAExecutionProvider" not in available:
            raise PegasusError("--device cuda: this onnxruntime has no CUDA provider (install onnxruntime-gpu)")
        use_cuda = device in ("cuda", "auto") and "CUDAExecutionProvider" in available
        providers = (["CUDAExecutionProvider"] if use_cuda else []) + ["CPUExecutionProvider"]
        try:
            self.session = onnxruntime.InferenceSession(str(path), providers=providers)
        except Exception as exc:  # onnxruntime raises its own exception types for bad files
            raise PegasusError(f"{path}: onnxruntime cannot load it ({exc})") from exc
        meta = self.session.get_modelmeta().custom_metadata_map
        if not {"object", "input_short_side", "config"} <= meta.keys():
            raise PegasusError(f"{path}: no object/input_short_side/config metadata; export it with `pegasus export`")
        self.config = config_from_dict(_metadata(meta, "config", json.loads, path), f"{path}: metadata config")
        self.object = target_object(_metadata(meta, "object", json.loads, path), f"{path}: metadata object",
                                    self.config.keypoints)
        self.short_side = _metadata(meta, "input_short_side", int, path)
        self.focal_px = _metadata(meta, "input_focal_px", float, path) if "input_focal_px" in meta else 0.0
        if self.short_side <= 0 or not (np.isfinite(self.focal_px) and self.focal_px >= 0):
            raise PegasusError(f"{path}: metadata input_short_side {self.short_side} / input_focal_px {self.focal_px}: "
                               "a positive size and a finite focal length >= 0 (px) expected")
        self.backend = "onnxruntime-" + ("cuda" if use_cuda else "cpu")
        self.device = torch.device("cuda" if use_cuda and torch.cuda.is_available() else "cpu")  # memory checks
        self.model = None

    def _init_torch(self, path: Path, device: str) -> None:
        state = load_checkpoint(path)
        self.device = torch_device(device)
        self.model = inference_network(model_from_checkpoint(state), self.device)
        self.config = self.model.config
        self.object = TargetObject(**state["object"])
        self.short_side = int(state["train_config"]["size"])
        self.focal_px = float(state["train_config"].get("focal_px", 0.0))
        self.backend = f"torch-{self.device.type}"

    def _check_memory(self, w: int, h: int, nw: int, nh: int) -> None:
        """A PegasusError when the network input of a ``w`` x ``h`` px image, ``nw`` x ``nh`` px, needs more
        memory than the device has (``model.memory_estimate``); each input size is checked once."""
        size = (nh + -nh % STRIDE, nw + -nw % STRIDE)
        if size not in self._sizes_checked:
            check_memory(memory_estimate(self.config, *size), self.device,
                         f"{self.path}: a {w}x{h} px image scaled to a {nw}x{nh} px network input (input_short_side "
                         f"{self.short_side}, input_focal_px {self.focal_px:g})")
            self._sizes_checked.add(size)

    def maps(self, image: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None,
                                                               tuple[float, float]]:
        """The last stage's beliefs [K + 1, h, w], affinities [2 K, h, w] and distance codes [h, w] (None without a
        distance head) for an RGB image [H, W, 3] uint8 seen with intrinsics K [3, 3], and the (x, y) scale from
        image to network-input pixels."""
        h, w = image.shape[:2]
        s = input_scale((h, w), K, self.short_side, self.focal_px)
        nw, nh = max(round(w * s), 1), max(round(h * s), 1)
        self._check_memory(w, h, nw, nh)
        resized = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
        pw, ph = -nw % STRIDE, -nh % STRIDE
        x = np.pad(resized, ((0, ph), (0, pw), (0, 0))).transpose(2, 0, 1)[None].astype(np.float32) / 255.0
        if self.model is None:
            outputs = self.session.run(None, {"image": x})
        else:
            outputs = network_outputs(self.model, x)
        distance = outputs[2][0, 0] if len(outputs) == 3 else None
        return outputs[0][0], outputs[1][0], distance, (nw / w, nh / h)

    def estimate(self, image: np.ndarray, K: np.ndarray, dist: np.ndarray | None = None,
                 min_score: float = 0.1, depth_m: np.ndarray | None = None,
                 mesh: tuple[np.ndarray, np.ndarray] | None = None) -> list[ObjectPose]:
        """Poses of the object's instances in an RGB image [H, W, 3] uint8 seen with intrinsics K [3, 3]
        (and OpenCV distortion ``dist``), best score first; instances PnP cannot solve are left out. With
        ``depth_m`` [H, W] (metres, aligned to the image, 0 = none) each pose is also refined against it, and
        an instance PnP cannot solve is kept (T None) when its refinement from the centroid's ray is accepted.
        With ``mesh`` (the object's vertices [V, 3] in metres, model frame, and faces [F, 3]; best through
        ``refine_rgb.decimated``) and no depth, each pose is also refined against the image (``refine_rgb``;
        a pinhole camera: no ``dist``). With a zoom network, an undistorted image (no ``dist``), and each pose scored
        by its detection score times its outline's support after the looks (``ObjectPose.score``), ``min_score``
        applying to that."""
        if depth_m is not None and self.surface is None:
            raise PegasusError(f"{self.path}: this model carries no surface points of its object (trained on a "
                               "DOPE/NDDS folder), so it cannot be refined with depth")
        if mesh is not None and (depth_m is not None or dist is not None):
            raise PegasusError("refinement against the RGB image takes an undistorted image without depth")
        if self.zoom is not None and dist is not None:
            raise PegasusError("the zoom network takes an undistorted image (no distortion coefficients)")
        beliefs, affinities, distance, (sx, sy) = self.maps(image, K)
        if not self.use_distance_head:
            distance = None
        def to_image(points: np.ndarray) -> np.ndarray:  # network-input px [..., 2] -> image px
            return (points + 0.5) / [sx, sy] - 0.5

        poses = []
        for det in find_keypoints(beliefs, affinities, stride=STRIDE, min_score=min_score):
            keypoints = to_image(det.keypoints)
            candidates = [np.column_stack([to_image(c[:, :2]), c[:, 2]]) for c in det.candidates]
            T, error, keypoints = solve_pose_consensus(keypoints, candidates, self.points, K,
                                                       CONSENSUS_TAU_PX / np.sqrt(sx * sy), dist) \
                or (None, np.nan, keypoints)
            if T is None and depth_m is None:
                continue
            if T is not None and distance is not None:
                code = read_map(distance, det.keypoints[-1], STRIDE)
                z = float(distance_from_code(code, mapped_focal(K, np.diag([sx, sy]))))
                if self.config.distance_off_axis:
                    z /= float(off_axis_factor(centroid_ray(keypoints[-1], K, dist)))
                T = on_centroid_ray(T, self.points, keypoints[-1], K, dist, z_m=z)
            support = None
            if T is not None and self.zoom is not None:
                T = self.zoom.refine(image, K, T)
                support = outline_support(image, K, T, *self.zoom.mesh)
            pose = ObjectPose(T, det.score, keypoints, error, support=support)
            if mesh is None and pose.score < min_score:  # refined against the image, its refinement scores it
                continue
            if depth_m is not None:
                start = on_centroid_ray(NO_PNP_START if T is None else T, self.points, keypoints[-1], K, dist, depth_m)
                pose.refinement = refine_multistart(start, depth_m, K, *self.surface, self.object.symmetry_axis)
                if pose.T is None and not pose.refinement.accepted:
                    continue
            elif mesh is not None:
                pose.rgb_refinement = refine_rgb(image, K, T, *mesh)
            poses.append(pose)
        return sorted(poses, key=lambda p: -p.score)

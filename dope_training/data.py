"""Training data for DOPE: BOP datasets (and DOPE/NDDS json folders) -> images with P keypoints per
instance -> augmented crops with belief and affinity targets, and distance targets for a distance head.

A sample is one image and its instances of the target objects: the keypoints (DOPE's 9: the cuboid corners of
the model's bounding box in DOPE's order, then its centre; or other object points, the centre last:
``dope_training.keypoints``) projected with the GT pose and K, in pixels.
Instances seen less than ``min_visibility`` (BOP visib_fract) are dropped: their keypoints do not
become targets.

Objects whose shape is rotationally symmetric (``symmetry_axis``) get canonical labels: the image alone does
not fix the angle about the axis, so keypoints of the GT rotation would sit at places the network cannot
tell from the pixels, and it learns their average (corners pulled towards the centroid, PnP placing the
object too far). Each instance's pose is therefore turned about the axis so that the model's reference
direction (the one of x, y, z nearest to perpendicular to the axis, made perpendicular) points at the
camera (``canonical_pose``); the pose is the same shape in the same place, so ADD-S and a grasp are
unchanged, and the angle about the axis that inference returns is the camera-facing one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from dope_training.backgrounds import behind_objects, masks_union, photo_view, warp_alpha
from dope_training.targets import (
    SIGMA_PX,
    distance_code,
    make_distance_targets,
    make_targets,
    mapped_focal,
    off_axis_factor,
)
from pegasus_gen.errors import PegasusError
from pegasus_gen.formats.bop import IMAGE_EXTENSIONS, bop_frames, model_boxes, object_names
from pegasus_gen.geometry.cuboid import cuboid_points, project_points
from pegasus_gen.io.files import read_json
from pegasus_gen.io.images import read_rgb

HIDDEN_VISIBILITY = 0.8  # an instance seen less than this (BOP visib_fract) counts as partly hidden


@dataclass
class Sample:
    """One image: its path, K [3, 3] and per instance its P keypoints [P, 2] (px), obj_id, visibility and the
    depth of its model box's centre (m, camera z; NaN where the data do not say: DOPE/NDDS folders), and the
    visible masks of every labelled instance in it, target or not (BOP's mask_visib; none in DOPE/NDDS folders)."""

    image: Path
    K: np.ndarray
    keypoints: list[np.ndarray] = field(default_factory=list)
    obj_ids: list[int] = field(default_factory=list)
    visibility: list[float] = field(default_factory=list)
    depths: list[float] = field(default_factory=list)
    masks: list[Path] = field(default_factory=list)


def resolve_objects(objects, boxes: dict, names: dict[str, int], where: str) -> list[int]:
    """obj_ids of ``objects`` given as ids or names; a clear error for an unknown one."""
    ids = []
    for obj in objects:
        if isinstance(obj, str) and not obj.isdigit():
            if obj not in names:
                raise PegasusError(f"{where}: no object named {obj!r} (known: {', '.join(sorted(names)) or 'none'})")
            ids.append(names[obj])
        else:
            if int(obj) not in boxes:
                raise PegasusError(f"{where}: no object with obj_id {obj} (known: {sorted(boxes)})")
            ids.append(int(obj))
    return ids


def check_K(K: np.ndarray, where: str) -> None:
    """A PegasusError naming ``where`` unless K [3, 3] (px) is a pinhole camera's: fx, fy > 0, every entry
    finite, last row (0, 0, 1)."""
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0 or (K[2] != (0, 0, 1)).any():
        raise PegasusError(f"{where}: K {np.round(K, 3).tolist()} is not a camera's (fx, fy > 0, all finite, "
                           "last row 0 0 1)")


def canonical_pose(T_cam_obj: np.ndarray, axis) -> np.ndarray:
    """T_cam_obj [4, 4] turned about ``axis`` [3] (object frame, through its origin) so that the reference
    direction (see the module docstring) points at the camera; unchanged when the camera looks along the axis."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    reference = np.eye(3)[np.argmin(np.abs(a))]
    reference = reference - (reference @ a) * a
    reference /= np.linalg.norm(reference)
    camera = -T_cam_obj[:3, :3].T @ T_cam_obj[:3, 3]  # the camera centre in the object frame
    towards = camera - (camera @ a) * a
    if np.linalg.norm(towards) < 1e-9:
        return T_cam_obj.copy()
    angle = np.arctan2(np.cross(reference, towards) @ a, reference @ towards)
    S = np.eye(4)
    S[:3, :3] = Rotation.from_rotvec(angle * a).as_matrix()
    return T_cam_obj @ S


def load_bop(root: str | Path, objects, split: str = "train_pbr", min_visibility: float = 0.1,
             symmetry_axis=None, keep_empty: bool = False,
             keypoints: dict[int, np.ndarray] | None = None) -> list[Sample]:
    """Samples of every image of a BOP split holding at least one visible instance of ``objects``
    (obj_ids or names), and with ``keep_empty`` of the other images too (no keypoints: negative examples);
    with ``symmetry_axis`` [3] (object frame), canonical labels (``canonical_pose``); ``keypoints``: {obj_id:
    [P, 3] object points (m, model frame), the centre last} projected instead of that object's cuboid."""
    root = Path(root)
    split_dir = root / split
    boxes = model_boxes(root)
    wanted = set(resolve_objects(objects, boxes, object_names(root), str(root)))
    points = {k: cuboid_points(*boxes[k]) for k in wanted} | {k: np.asarray(v, np.float64)
                                                              for k, v in (keypoints or {}).items() if k in wanted}
    samples = []
    for frame in bop_frames(split_dir):
        where = f"{frame.scene}: image {frame.im_id}"
        check_K(frame.K, f"{where} (scene_camera.json)")
        sample = Sample(frame.image, frame.K, masks=frame.visible_masks())
        for inst in frame.instances:
            visib = 1.0 if inst.visib_fract is None else inst.visib_fract
            if inst.obj_id in wanted and visib >= min_visibility:
                T = inst.T if symmetry_axis is None else canonical_pose(inst.T, symmetry_axis)
                projected = project_points(points[inst.obj_id], T, frame.K)
                if not np.isfinite(projected).all():
                    raise PegasusError(f"{where} (scene_gt.json), instance {inst.index}: the pose "
                                       f"{np.round(inst.T[:3], 4).tolist()} does not project the object to finite "
                                       "pixels (not finite, or its centre on the camera plane)")
                sample.keypoints.append(projected)
                sample.obj_ids.append(inst.obj_id)
                sample.visibility.append(visib)
                sample.depths.append(float(T[2, :3] @ points[inst.obj_id][-1] + T[2, 3]))
        if sample.keypoints or keep_empty:
            samples.append(sample)
    return samples


def load_ndds(folder: str | Path, classes, min_visibility: float = 0.1) -> list[Sample]:
    """Samples from a DOPE/NDDS folder (image + same-name .json with camera_data and objects[].projected_cuboid),
    keeping objects whose ``class`` is in ``classes``; obj_ids number the classes from 1 in the given order."""
    folder = Path(folder)
    ids = {str(c): i + 1 for i, c in enumerate(classes)}
    samples = []
    for doc_path in sorted(folder.rglob("*.json")):
        image = next((doc_path.with_suffix(e) for e in IMAGE_EXTENSIONS if doc_path.with_suffix(e).is_file()), None)
        doc = read_json(doc_path)
        if image is None or "objects" not in doc:
            continue  # settings files and the like
        intr = doc.get("camera_data", {}).get("intrinsics", {})
        K = np.array([[intr.get("fx", 0), 0, intr.get("cx", 0)], [0, intr.get("fy", 0), intr.get("cy", 0)], [0, 0, 1]],
                     dtype=np.float64)
        check_K(K, f"{doc_path} (camera_data.intrinsics)")
        sample = Sample(image, K)
        for obj in doc["objects"]:
            points = np.asarray(obj.get("projected_cuboid", []), dtype=np.float64)
            if obj.get("class") not in ids or points.shape != (9, 2) or obj.get("visibility", 1) < min_visibility:
                continue
            if not np.isfinite(points).all():
                raise PegasusError(f"{doc_path}: the projected_cuboid of a {obj['class']!r} is not finite")
            sample.keypoints.append(points)
            sample.obj_ids.append(ids[obj["class"]])
            sample.visibility.append(float(obj.get("visibility", 1)))
            sample.depths.append(np.nan)
        if sample.keypoints:
            samples.append(sample)
    if not samples:
        raise PegasusError(f"{folder}: no DOPE/NDDS json with objects of class {', '.join(map(str, classes))}")
    return samples


@dataclass
class Augment:
    """Random crop/scale/rotation (one affine warp, constant random-colour borders: no mirrored copies of
    objects), optics blur, colour jitter and noise."""

    scale: tuple[float, float] = (0.75, 1.25)  # relative to fitting the image's shorter side into the crop
    rotation_deg: float = 15.0
    shift: float = 0.2  # fraction of the crop by which the crop centre moves off the chosen instance
    brightness: float = 0.25
    contrast: float = 0.25
    saturation: float = 0.25
    hue_deg: float = 6.0
    noise_std: float = 4.0  # grey levels
    blur_px: float = 0.0  # half the crops blurred by a Gaussian of std drawn from 0..this (crop px); 0: none
    linear_light: bool = False  # blur the light (sRGB decoded, blurred, encoded again) as a lens does, not the code
    enabled: bool = True


def input_scale(image_hw: tuple[int, int], K: np.ndarray, size: int, focal_px: float = 0.0) -> float:
    """The nominal scale from image to network-input pixels, which training and inference share: with
    ``focal_px`` > 0 the image is scaled so that its fx (K [3, 3], px) becomes ``focal_px`` (an object at a
    given distance then looks the same size to the network whatever the camera); with 0, DOPE's policy: the
    image's shorter side fitted into ``size`` px."""
    return focal_px / float(K[0, 0]) if focal_px > 0 else size / min(image_hw)


def crop_transform(size: int, base: float, centre: np.ndarray, rng: np.random.Generator, aug: Augment) -> np.ndarray:
    """[2, 3] affine map from image pixels to crop pixels [size, size]: the nominal scale ``base``
    (``input_scale``), randomly scaled, rotated about and centred near ``centre`` [2] (px). Without
    augmentation: the nominal scale, centred on ``centre``."""
    if not aug.enabled:
        return np.array([[base, 0, (size - 1) / 2 - base * centre[0]], [0, base, (size - 1) / 2 - base * centre[1]]])
    s = base * rng.uniform(*aug.scale)
    a = np.radians(rng.uniform(-aug.rotation_deg, aug.rotation_deg))
    R = s * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    target = (size - 1) / 2 + rng.uniform(-aug.shift, aug.shift, 2) * size
    return np.concatenate([R, (target - R @ centre)[:, None]], axis=1)


def occluder_mask(size: int, box: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """[S, S] bool: a random polygon of 5-9 corners centred on a random point of ``box`` [4] (x0, y0, x1, y1; crop
    px) with an area of 15-50 % of the box's on average: the shape of a cut-out occluder."""
    centre = rng.uniform(box[:2], box[2:])
    radius = np.sqrt(max(box[2] - box[0], 1.0) * max(box[3] - box[1], 1.0) * rng.uniform(0.15, 0.5) / np.pi)
    angles = np.sort(rng.uniform(0, 2 * np.pi, rng.integers(5, 10)))
    radii = radius * rng.uniform(0.6, 1.3, len(angles))
    corners = centre + radii[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    mask = np.zeros((size, size), np.uint8)
    cv2.fillPoly(mask, [np.round(corners).astype(np.int32)], 1)
    return mask.astype(bool)


# sRGB's decoding of the 256 codes to linear light 0..1 (IEC 61966-2-1)
_CODES = np.arange(256) / 255.0
SRGB_TO_LINEAR = np.where(_CODES <= 0.04045, _CODES / 12.92, ((_CODES + 0.055) / 1.055) ** 2.4).astype(np.float32)


def blur_light(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """[H, W, 3] uint8 sRGB blurred by a Gaussian of std ``sigma_px`` (px) in linear light, then encoded again: a
    lens spreads light and the camera encodes afterwards, so a dark object's edge against a bright background
    moves into the object (blurring the codes themselves keeps every edge in place)."""
    light = np.clip(cv2.GaussianBlur(SRGB_TO_LINEAR[image], (0, 0), sigmaX=sigma_px), 0.0, 1.0)
    code = np.where(light <= 0.0031308, 12.92 * light, 1.055 * light ** (1 / 2.4) - 0.055)
    return np.rint(255.0 * code).astype(np.uint8)


def jitter_colour(image: np.ndarray, rng: np.random.Generator, aug: Augment) -> np.ndarray:
    """[H, W, 3] uint8 RGB, for half the images (with ``aug.blur_px`` > 0) blurred as a softer lens would (in
    linear light with ``aug.linear_light``), with random brightness, contrast, saturation, hue and Gaussian noise
    (the sensor's, after the blur)."""
    if aug.blur_px > 0 and rng.uniform() < 0.5:
        sigma = max(rng.uniform(0, aug.blur_px), 1e-3)
        image = blur_light(image, sigma) if aug.linear_light else cv2.GaussianBlur(image, (0, 0), sigmaX=sigma)
    hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV).astype(np.float32)
    hsv[..., 0] = (hsv[..., 0] + rng.uniform(-aug.hue_deg, aug.hue_deg) / 2) % 180  # OpenCV hue: 0..180
    hsv[..., 1] *= 1 + rng.uniform(-aug.saturation, aug.saturation)
    out = cv2.cvtColor(np.clip(hsv, 0, 255).astype(np.uint8), cv2.COLOR_HSV2RGB).astype(np.float32)
    mean = out.mean()
    out = (out - mean) * (1 + rng.uniform(-aug.contrast, aug.contrast)) + mean
    out = out * (1 + rng.uniform(-aug.brightness, aug.brightness))
    out += rng.normal(0, aug.noise_std, out.shape)
    return np.clip(out, 0, 255).astype(np.uint8)


class DopeDataset(torch.utils.data.Dataset):
    """Samples -> (image [3, S, S] float 0..1 RGB, beliefs [P, S/8, S/8], affinities [2 (P - 1), S/8, S/8], distance
    [1, S/8, S/8] and its weight [1, S/8, S/8]: ``targets.make_distance_targets`` at the crop's focal length; with
    ``off_axis`` of each instance's depth times ``targets.off_axis_factor`` of its centre's ray in the frame).

    Each item draws its augmentation from a generator seeded by (seed, epoch, index), so runs repeat: ``ds[i]``
    is item i of epoch ``ds.epoch``, ``ds[(epoch, i)]`` that of the given epoch (what a sampler hands the loader's
    workers, whose copies of the dataset keep the epoch they started with). A crop
    is centred near one of the sample's instances, or, for a share ``negatives`` of the items and for samples
    without instances, on a random point of the image: background, clutter and other objects, where the
    network must learn to find nothing (an instance the crop happens to hold keeps its targets). A share
    ``occluders`` of the crops centred on an instance get a cut-out of another sample's image (a random place in
    it, at its nominal scale; ``occluder_mask``'s shape) pasted over part of that instance, whose targets stay
    whole: the network learns to read a partly hidden object's pose from what shows. A share ``backgrounds``
    of all crops (of samples with masks) show one of ``photos`` ([H, W, 3] uint8 RGB) behind the labelled objects
    instead of the rendered environment and distractors (``backgrounds.behind_objects``).

    Each item reads its frame's image (and masks) from disk unless ``preload`` decoded them all once (a training
    run reads each frame once per epoch: decoding was a fifth of a CPU training step's time).
    """

    def __init__(self, samples: list[Sample], size: int = 400, augment: Augment | None = None, seed: int = 0,
                 stride: int = 8, focal_px: float = 0.0, sigma_px: float = SIGMA_PX, negatives: float = 0.0,
                 occluders: float = 0.0, backgrounds: float = 0.0, photos: list[np.ndarray] | None = None,
                 off_axis: bool = False):
        if backgrounds > 0 and not photos:
            raise PegasusError("backgrounds > 0 needs background photos")
        if size % stride:
            raise PegasusError(f"input size {size} must be a multiple of the network stride {stride}")
        self.samples, self.size, self.stride, self.seed, self.focal_px = samples, size, stride, seed, focal_px
        self.sigma_px, self.negatives, self.occluders = sigma_px, negatives, occluders
        self.backgrounds, self.photos = backgrounds, photos or []
        self.off_axis = off_axis
        self.points = next((len(s.keypoints[0]) for s in samples if s.keypoints), 9)  # P: keypoints per instance
        self.augment = augment or Augment()
        self.epoch = 0
        self._images: list[np.ndarray] | None = None
        self._unions: list[np.ndarray | None] | None = None

    def __len__(self) -> int:
        return len(self.samples)

    def preload(self, max_bytes: int) -> bool:
        """Decode every sample's image and (when ``backgrounds`` uses them) its masks' union into memory, if they
        fit in ``max_bytes`` (judged by the first image's size); returns whether they did. Loader processes forked
        afterwards share them."""
        if not self.samples:
            return False
        height, width = read_rgb(self.samples[0].image).shape[:2]
        masks = self.augment.enabled and self.backgrounds > 0 and any(s.masks for s in self.samples)
        if len(self.samples) * height * width * (4 if masks else 3) > max_bytes:
            return False
        frames = [(read_rgb(s.image), masks_union(s.masks) if masks else None)
                  for s in tqdm(self.samples, desc="decoding frames", unit="frame", mininterval=2.0)]
        self._images = [image for image, _ in frames]
        self._unions = [union for _, union in frames] if masks else None
        return True

    def image(self, index: int) -> np.ndarray:
        """Sample ``index``'s image [H, W, 3] uint8 RGB (decoded by ``preload`` or read now)."""
        return self._images[index] if self._images is not None else read_rgb(self.samples[index].image)

    def union(self, index: int) -> np.ndarray | None:
        """Sample ``index``'s visible masks' union [H, W] uint8 (``backgrounds.masks_union``; None without masks),
        decoded by ``preload`` or read now."""
        return self._unions[index] if self._unions is not None else masks_union(self.samples[index].masks)

    def item(self, index: int, epoch: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The augmented crop [S, S, 3] uint8 RGB, its keypoints [I, P, 2] (crop pixels) and the affine
        [2, 3] from image to crop pixels, of ``epoch`` (default ``self.epoch``)."""
        sample = self.samples[index]
        rng = np.random.default_rng([self.seed, self.epoch if epoch is None else epoch, index])
        image = self.image(index)
        keypoints = np.stack(sample.keypoints) if sample.keypoints else np.zeros((0, self.points, 2))
        chosen = None
        if not len(keypoints) or (self.negatives > 0 and rng.uniform() < self.negatives):
            centre = rng.uniform((0, 0), image.shape[1::-1])
        else:
            chosen = rng.integers(len(keypoints))
            centre = keypoints[chosen, -1]
        base = input_scale(image.shape[:2], sample.K, self.size, self.focal_px)
        M = crop_transform(self.size, base, centre, rng, self.augment)
        border = tuple(int(v) for v in rng.integers(0, 256, 3)) if self.augment.enabled else (0, 0, 0)
        crop = cv2.warpAffine(image, M, (self.size, self.size), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=border)
        moved = keypoints @ M[:, :2].T + M[:, 2]
        if self.augment.enabled and sample.masks and self.backgrounds > 0 and rng.uniform() < self.backgrounds:
            alpha = warp_alpha(self.union(index), M, self.size)
            crop = behind_objects(crop, alpha, photo_view(self.photos, self.size, rng))
        if (self.augment.enabled and chosen is not None and len(self.samples) > 1 and self.occluders > 0
                and rng.uniform() < self.occluders):
            crop = self.occlude(crop, moved[chosen], index, rng)
        if self.augment.enabled:
            crop = jitter_colour(crop, rng, self.augment)
        return crop, moved, M

    def occlude(self, crop: np.ndarray, keypoints: np.ndarray, index: int, rng: np.random.Generator) -> np.ndarray:
        """``crop`` [S, S, 3] uint8 with a cut-out of another sample's image than ``index`` pasted over part of the
        instance whose keypoints [P, 2] (crop px) are given."""
        other = rng.integers(len(self.samples) - 1)
        other += other >= index
        source, image = self.samples[other], self.image(other)
        base = input_scale(image.shape[:2], source.K, self.size, self.focal_px)
        M = crop_transform(self.size, base, rng.uniform((0, 0), image.shape[1::-1]), rng, self.augment)
        patch = cv2.warpAffine(image, M, (self.size, self.size), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REFLECT_101)
        mask = occluder_mask(self.size, np.concatenate([keypoints.min(0), keypoints.max(0)]), rng)
        out = crop.copy()
        out[mask] = patch[mask]
        return out

    def __getitem__(self, key: int | tuple[int, int]):
        epoch, index = key if isinstance(key, tuple) else (self.epoch, key)
        crop, keypoints, M = self.item(index, epoch)
        beliefs, affinities = make_targets(keypoints, np.ones(keypoints.shape[:2], bool), self.size, self.size,
                                           stride=self.stride, sigma_px=self.sigma_px)
        sample = self.samples[index]
        focal = mapped_focal(sample.K, M[:, :2])  # the crop's, px
        depths = sample.depths if len(sample.depths) == len(keypoints) else np.full(len(keypoints), np.nan)
        if self.off_axis and len(keypoints):
            centres = np.array([[*k[-1], 1.0] for k in sample.keypoints])
            depths = depths * off_axis_factor((centres @ np.linalg.inv(sample.K).T)[:, :2])
        distance, weight = make_distance_targets(keypoints[:, -1], distance_code(depths, focal), self.size, self.size,
                                                 self.stride, self.sigma_px)
        image = torch.from_numpy(np.ascontiguousarray(crop)).permute(2, 0, 1).float() / 255.0
        return image, *(torch.from_numpy(t) for t in (beliefs, affinities, distance, weight))

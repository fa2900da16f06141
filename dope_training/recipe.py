"""The sim-to-real recipe: training data and training settings for one object seen by one real camera,
chosen from the object's size and the camera alone (``benchmarks/real.py``; docs/TRAINING.md says what each
choice did on real photos).

Scale: the network sees every object at one size. ``focal_px`` is chosen so that the object's diameter spans
``OBJECT_PX`` network-input pixels at the middle of the working distances (at most ``MAX_ENLARGE`` times the
camera's fx: a small object's real images are enlarged for the network), and the training images are rendered
at that focal length or the camera's own, whichever is lower, so that a training image is never sharper than
the real camera's at the network's scale. The crop holds the object with context around it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dope_training.targets import STRIDE

OBJECT_PX = 64.0  # the object's diameter in network-input pixels at the middle distance
MAX_ENLARGE = 2.0  # the network-input focal length is at most this many times the camera's fx
CROP_PX = 128
NEGATIVES = 0.3
BACKGROUNDS = 0.5  # share of the crops with a real photograph behind the objects (docs/TRAINING.md run DD)
# a real camera's softer optics and colours: half the crops blurred (std up to this, network-input px), brightness,
# contrast and saturation within 1 -/+ COLOUR_JITTER (run AA in docs/TRAINING.md)
BLUR_PX = 1.5
COLOUR_JITTER = 0.4
# every crop's hue turned by up to this (degrees) either way: a scan's colours come from another camera under other
# light than the robot's (run KK in docs/TRAINING.md)
HUE_DEG = 30.0
VARIANT = "pretrained"  # the network the recipe trains (TrainConfig.variant)
# the object points the network learns: 8 on the model's surface instead of the box's corners (run MM in
# docs/TRAINING.md: rotation on generated frames halved, the photos' AUC and 0.1 d recall up on five of six networks)
KEYPOINTS = "surface"
# the detection score is the lowest at which the network leaves this many false positives per image on generated
# held-out frames and still finds this share of the instances it finds there (evaluate.score_threshold): generated
# frames hold far fewer look-alikes than photos, so their false positives alone set too low a score
HELD_OUT_FALSE_POSITIVES = 0.25
HELD_OUT_KEEP_FOUND = 0.95


@dataclass(frozen=True)
class RealCamera:
    """A real camera: intrinsics K [3, 3] (px) and image size (px)."""

    K: np.ndarray
    width: int
    height: int


def network_focal(diameter_m: float, distance_m: tuple[float, float], camera: RealCamera) -> float:
    """The network-input focal length (px): the object's diameter (m) spans OBJECT_PX at the middle of
    ``distance_m`` (m), at most MAX_ENLARGE times the camera's fx."""
    middle = 0.5 * (distance_m[0] + distance_m[1])
    return float(min(OBJECT_PX * middle / diameter_m, MAX_ENLARGE * camera.K[0, 0]))


def training_camera(focal_px: float, camera: RealCamera) -> dict:
    """The generate config's camera for training images at ``focal_px``: the real camera scaled by focal_px /
    fx, at most 1 (size rounded to a multiple of STRIDE), fields of ``CameraConfig``."""
    s = min(focal_px / camera.K[0, 0], 1.0)
    width, height = (max(STRIDE, STRIDE * round(v * s / STRIDE)) for v in (camera.width, camera.height))
    sx, sy = width / camera.width, height / camera.height
    return {"width": width, "height": height, "fx": round(camera.K[0, 0] * sx, 3), "fy": round(camera.K[1, 1] * sy, 3),
            "cx": round((camera.K[0, 2] + 0.5) * sx - 0.5, 3), "cy": round((camera.K[1, 2] + 0.5) * sy - 0.5, 3)}


def train_fields(focal_px: float, epochs: int) -> dict:
    """TrainConfig fields of the recipe: CROP_PX crops at ``focal_px``, the demo's optimiser settings,
    NEGATIVES of the crops on random points of the image, BACKGROUNDS of them with a real photograph behind the
    objects, blur and colour jitter as a real camera's, the hue turned by up to HUE_DEG, KEYPOINTS on the object's
    surface, and a distance head (the distance from how large the object looks, not from the spread of its
    keypoints)."""
    return {"size": CROP_PX, "focal_px": round(focal_px, 3), "epochs": epochs, "lr": 2e-3,
            "schedule": "cosine", "peak_weight": 10.0, "negatives": NEGATIVES, "backgrounds": BACKGROUNDS,
            "blur_px": BLUR_PX, "colour_jitter": COLOUR_JITTER, "hue_deg": HUE_DEG, "keypoints": KEYPOINTS,
            "distance_head": True}

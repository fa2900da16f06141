"""The configuration of a DOPE training run (``pegasus train``, trainer_node): every knob with its default,
typed and checked; the variant's defaults filled in when it is built. Light to import (no torch)."""

from __future__ import annotations

from typing import Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, model_validator

from dope_training.targets import MIN_KEYPOINTS, SIGMA_PX
from pegasus_gen.errors import PegasusError
from pegasus_gen.io.files import parse_yaml


class TrainConfig(BaseModel):
    """One training run. ``size``/``lr`` of 0 take the variant's default (full: 400 px, 1e-4 as DOPE;
    light: 320 px, 1e-3), filled in when the config is built."""

    model_config = ConfigDict(extra="forbid")

    data: list[str] = Field(min_length=1, description="BOP dataset roots or DOPE/NDDS folders")
    object: str = Field(min_length=1, description="obj_id or name (BOP), class name (NDDS)")
    out: str = Field("runs/dope", description="output folder (checkpoints, loss curve, belief snapshots)")
    split: str = Field("train_pbr", description="BOP split to train on")
    variant: Literal["full", "light", "pretrained"] = Field(
        "light", description="full: the original DOPE (GPU); light: 3 narrow stages for CPU; pretrained: light's "
                             "stages on an ImageNet-pretrained EfficientNet-Lite0 trunk")
    distance_head: bool = Field(False, description="a branch after the last stage that learns each object's distance "
                                "from how large it looks; inference then places the object at that distance on the "
                                "ray through its centroid instead of PnP's")
    distance_off_axis: bool = Field(True, description="the distance head's off-axis correction: it learns the depth "
                                    "at which the object would look as large on the optical axis, which its look "
                                    "alone tells (an object off the axis looks larger at the same depth); off: the "
                                    "depth itself")
    distance_grad: float = Field(0.0, ge=0.0, le=1.0, description="share of the distance head's gradient that reaches "
                                 "the stages and the trunk (0: the head reads them detached and its loss trains it "
                                 "alone)")
    batch_norm: Optional[bool] = Field(None, description="BatchNorm after every hidden convolution (default: the "
                                                         "variant's: light yes, full no)")
    size: int = Field(0, ge=0, description="crop size, px (default: full 400, light 320)")
    focal_px: float = Field(0.0, ge=0.0, description="network-input focal length, px: images are scaled so that "
                            "their fx becomes this (objects look alike to the network from any camera); 0: "
                            "DOPE's policy, the image's shorter side fitted into the crop")
    epochs: int = Field(10, gt=0, description="epochs in all (a resumed run trains up to this)")
    batch_size: int = Field(8, gt=0, description="per process")
    lr: float = Field(0.0, ge=0.0, description="Adam learning rate (default: full 1e-4, light 1e-3)")
    schedule: Literal["constant", "cosine"] = Field(
        "constant", description="learning rate over the run: constant (DOPE), or cosine decay to 1/100 of lr")
    peak_weight: float = Field(0.0, ge=0.0, description="belief cells' squared error weighted by 1 + this * target "
                                                        "(DOPE: 0)")
    keypoints: Literal["cuboid", "surface"] = Field(
        "cuboid", description="the object points the network learns to find: cuboid (DOPE's: the model box's corners "
                              "and centre) or surface (surface_points farthest points on the model's surface "
                              "and the box's centre; BOP data)")
    surface_points: int = Field(8, ge=MIN_KEYPOINTS, le=32, description="with keypoints surface: how many points on "
                                "the model's surface the network finds (one belief and two affinity maps each)")
    symmetry_axis: Optional[tuple[float, float, float]] = Field(
        None, description="axis (object frame) about which the object's shape is rotationally symmetric: canonical "
                          "labels about it (default: the dataset's symmetries_continuous, if any)")
    sigma_px: float = Field(SIGMA_PX, gt=0.0, description="std of the belief targets' Gaussians, network-input px "
                                                          "(DOPE: 4, half a map cell)")
    min_visibility: float = Field(0.1, ge=0.0, le=1.0, description="skip instances seen less than this")
    negatives: float = Field(0.0, ge=0.0, le=1.0, description="share of crops centred on a random point of the image "
                             "instead of an instance, images without the object included: background and clutter "
                             "where nothing is to be found (BOP data)")
    hidden_share: float = Field(0.0, ge=0.0, lt=1.0, description="share of each epoch's draws given to the frames "
                                "where the object is under 0.8 visible (BOP visib_fract), drawn with replacement; 0: "
                                "every frame once per epoch")
    occluders: float = Field(0.0, ge=0.0, le=1.0, description="share of the crops on an instance with a cut-out of "
                             "another training image pasted over part of it (its targets kept): partly hidden "
                             "objects")
    backgrounds: float = Field(0.0, ge=0.0, le=1.0, description="share of the crops whose background (all but the "
                               "labelled objects, by BOP's visible masks) is a random view of a real photograph: "
                               "real-world textures where nothing is to be found")
    background_photos: Optional[str] = Field(None, description="folder of photos (PNG/JPEG) for backgrounds; "
                                             "default: the photographs bundled with scikit-image; every fourth "
                                             "is kept back for held-out frames (backgrounds.split_photos)")
    blur_px: float = Field(0.0, ge=0.0, description="half the crops blurred by a Gaussian whose std is drawn from "
                           "0 to this, network-input px: a real camera's softer optics (0: no blur)")
    blur_linear_light: bool = Field(False, description="blur_px's blur in linear light (sRGB decoded, blurred, "
                                    "encoded again) as a lens does: a dark object's outline moves into it against a "
                                    "bright background")
    colour_jitter: float = Field(0.25, ge=0.0, lt=1.0, description="brightness, contrast and saturation each "
                                 "scaled by a factor drawn from 1 -/+ this")
    hue_deg: float = Field(6.0, ge=0.0, le=180.0, description="every crop's hue turned by an angle drawn from -/+ "
                           "this (degrees): a scan's colours come from another camera under other light than the "
                           "photos the network will see")
    augment: bool = Field(True, description="random crop, scale, rotation and colour augmentation (without it: "
                                            "nominal-scale crops around the instances only)")
    device: Literal["auto", "cpu", "cuda"] = Field("auto", description="auto: CUDA when torch sees a GPU")
    amp: bool = Field(True, description="mixed precision (float16) on CUDA")
    loader_workers: int = Field(-1, ge=-1, description="data loading processes per training process (-1: 2 on the "
                                                        "CPU; on CUDA one per CPU core less one, at most 8)")
    frozen_blocks: int = Field(0, ge=0, le=11, description="pretrained variant: the trunk's stem and its first this "
                               "many blocks kept as ImageNet trained them (weights and BatchNorm statistics; 3: "
                               "everything at strides 2 and 4, a training step about 1.3x as fast)")
    seed: int = Field(0, description="random seed (weights, image order, augmentation)")
    vgg19: Optional[str] = Field(None, description="ImageNet VGG19 weights (torchvision vgg19-*.pth) for the "
                                                   "full variant; default: the torch hub cache if present")
    object_size: Optional[tuple[float, float, float]] = Field(
        None, description="model box size in metres (DOPE/NDDS data; BOP has models_info)")
    keep_checkpoints: int = Field(3, gt=0, description="newest epoch checkpoints kept")
    checkpoint_every: int = Field(1, gt=0, description="epochs between checkpoints, belief snapshots and "
                                                       "loss.png (and the last epoch)")
    checkpoint_minutes: float = Field(5.0, ge=0.0, description="and, after the first epoch's, at least this many "
                                      "minutes between them (a full network's checkpoint is ~600 MB; on a GPU an "
                                      "epoch can take seconds); 0: every checkpoint_every epochs")

    @model_validator(mode="after")
    def _variant_defaults(self) -> "TrainConfig":
        if self.frozen_blocks and self.variant != "pretrained":
            raise ValueError(f"frozen_blocks keeps ImageNet's trunk, which only the pretrained variant has "
                             f"(not {self.variant})")
        if self.keypoints == "cuboid" and self.surface_points != 8:
            raise ValueError("surface_points needs keypoints surface (the cuboid has 8 corners)")
        self.size = self.size or (400 if self.variant == "full" else 320)
        self.lr = self.lr or (1e-4 if self.variant == "full" else 1e-3)
        return self


def parse_options(text: str | list[str]) -> dict:
    """TrainConfig fields from "key=value key=value" (values parsed as YAML, e.g. "focal_px=330
    symmetry_axis=[0,0,1]"), or from a list of "key=value" items (a value may then hold spaces), as a dict;
    one clear error for an item without "=" or with bad YAML."""
    options = {}
    for item in text.split() if isinstance(text, str) else text:
        key, sep, value = item.partition("=")
        if not sep:
            raise PegasusError(f"training option {item!r} is not key=value")
        options[key] = parse_yaml(value, f"training option {item!r}")
    return options

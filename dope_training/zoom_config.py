"""The configuration of a zoom network's training run (``pegasus train-zoom``, ``dope_training.zoom_train``):
every knob with its default, typed and checked. Light to import (no torch)."""

from __future__ import annotations

from typing import Literal, Optional

from pydantic import BaseModel, ConfigDict, Field


class ZoomConfig(BaseModel):
    """One zoom network's training run."""

    model_config = ConfigDict(extra="forbid")

    data: list[str] = Field(min_length=1, description="BOP dataset roots")
    object: str = Field(min_length=1, description="obj_id or name")
    out: str = Field("runs/zoom.pt", description="the checkpoint written when training ends")
    split: str = Field("train_pbr", description="BOP split to train on")
    epochs: int = Field(8, gt=0, description="passes over the drawn crops")
    per_instance: int = Field(4, gt=0, description="estimates drawn around each instance")
    batch_size: int = Field(32, gt=0)
    lr: float = Field(1e-3, gt=0.0, description="AdamW's peak learning rate (one cycle)")
    # 96 px crops train in 0.55 of 128 px's time, the holepuncher's figures within 0.013 of AUC (docs/TRAINING.md, AD)
    crop_px: int = Field(96, gt=0, multiple_of=32, description="crop size, px")
    object_px: float = Field(66.0, gt=0.0, description="the object's diameter in the crop at the estimate's "
                             "distance, px")
    centre_std: float = Field(0.04, gt=0.0, description="the drawn estimates' centre aside: std, share of the "
                              "object's diameter in pixels")
    distance_std: float = Field(0.04, gt=0.0, description="the drawn estimates' log distance: std (at most 3 std)")
    rotation_std_deg: float = Field(12.0, ge=0.0, description="the drawn estimates' turn about a random axis: std, "
                                    "degrees")
    rotation: bool = Field(False, description="also learn the turn back to the true rotation (else the rotation is "
                           "kept)")
    view: Literal["silhouette", "colour", "normals"] = Field(
        "silhouette", description="what is rendered at the estimate beside the crop: the model's silhouette, with "
        "colour also its vertex colours shaded as under a light at the camera, with normals also its surface normals "
        "in the camera frame")
    look: Literal["offsets", "outline"] = Field(
        "offsets", description="offsets: regress the centre's and the distance's offsets (with rotation the turn "
        "too) from the crop and the view; outline: read each crop pixel's probability of showing the object and fit "
        "the model's outline to it, moving the whole pose (no view, no rotation output)")
    min_visibility: float = Field(0.1, ge=0.0, le=1.0, description="skip instances seen less than this")
    backgrounds: float = Field(0.5, ge=0.0, le=1.0, description="share of the crops with a real photograph behind "
                               "the objects")
    background_photos: Optional[str] = Field(None, description="folder of photos for backgrounds (default: "
                                             "scikit-image's; every fourth kept back as TrainConfig's)")
    occluders: float = Field(0.0, ge=0.0, le=1.0, description="share of the crops with part of the object hidden "
                             "behind a cut-out of another crop's surroundings")
    blur_px: float = Field(1.5, ge=0.0, description="half the crops blurred by a Gaussian of std up to this, px")
    colour_jitter: float = Field(0.4, ge=0.0, lt=1.0, description="brightness, contrast and saturation within 1 -/+ "
                                 "this")
    hue_deg: float = Field(30.0, ge=0.0, le=180.0, description="hue turned by up to this, degrees")
    device: Literal["auto", "cpu", "cuda"] = Field("auto", description="auto: CUDA when torch sees a GPU")
    seed: int = Field(0, description="random seed (drawn estimates, weights, order, augmentation)")

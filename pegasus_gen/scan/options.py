"""What a scan is asked to do (``pegasus scan``, :func:`pegasus_gen.scan.pipeline.run_scan`): every option with
its default, typed and checked together. Light to import (no SfM, no torch)."""

from __future__ import annotations

from typing import Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, model_validator

from pegasus_gen.assets.names import ASSET_NAME_PATTERN

TRAIN_SIZE = {"cpu-small": 160, "7k": 1600, "30k": 1600}  # default longest photo side for training, px, by preset


class ScanOptions(BaseModel):
    """Everything ``run_scan`` needs besides the photos. Lengths in metres, image sizes in pixels."""

    model_config = ConfigDict(extra="forbid")

    kind: Literal["object", "environment"] = Field("object", description="an object on a support, or a place")
    name: str = Field("scan", pattern=ASSET_NAME_PATTERN, description="asset name (letters, digits, _ . -)")
    obj_id: Optional[int] = Field(None, ge=1, description="BOP object id (objects)")
    aruco_size: Optional[float] = Field(None, gt=0, description="printed ArUco marker edge length, metres")
    aruco_dict: str = Field("DICT_4X4_50", description="cv2.aruco dictionary of the markers")
    scale: Optional[float] = Field(None, gt=0, description="metres per reconstruction unit, instead of markers")
    intrinsics: Optional[tuple[float, float, float, float]] = Field(
        None, description="calibrated pinhole camera fx, fy, cx, cy (OpenCV pixels); default: estimated by SfM")
    matcher: Literal["exhaustive", "sequential"] = Field(
        "exhaustive", description="exhaustive for up to ~150 photos, sequential for video-like sets")
    masks: Optional[str] = Field(None, description="folder of object masks named like the photos (background "
                                                   "removal; non-zero = object)")
    second_images: Optional[str] = Field(None, description="photos of the object turned over (two-part object "
                                                           "scan; needs masks)")
    second_masks: Optional[str] = Field(None, description="object masks of the second-half photos")
    preset: Literal["cpu-small", "7k", "30k"] = Field(
        "cpu-small", description="splat training length: cpu-small (minutes on a CPU), 7k or 30k iterations (GPU)")
    iterations: Optional[int] = Field(None, ge=1, description="training steps instead of the preset's (its "
                                                              "schedule is kept)")
    train_size: Optional[int] = Field(None, ge=1, description="longest photo side for splat training, pixels "
                                                              "(default 160 for cpu-small, else 1600)")
    holdout_every: int = Field(8, ge=1, description="every n-th registered photo is held out for PSNR")
    device: Literal["auto", "cpu", "cuda"] = Field("auto", description="where the splats train and render")
    seed: int = Field(0, description="random seed (SfM, alignment, training)")
    overwrite: bool = Field(False, description="replace an existing asset of that name")

    @model_validator(mode="after")
    def _consistent(self) -> "ScanOptions":
        if self.kind == "object" and self.obj_id is None:
            raise ValueError("an object scan needs --obj-id (an integer >= 1)")
        if self.scale is None and self.aruco_size is None:
            raise ValueError("metric scale needs --aruco-size (printed marker edge in metres) or --scale "
                             "(metres per reconstruction unit)")
        if self.second_images is not None and (self.kind != "object" or self.masks is None
                                               or self.second_masks is None):
            raise ValueError("a two-part object scan (--second-images) needs --masks and --second-masks: the "
                             "object moved against the board between the halves, so only its pixels can be matched")
        return self

    @property
    def training_size(self) -> int:
        """The longest photo side for splat training, pixels: ``train_size`` or the preset's."""
        return self.train_size or TRAIN_SIZE[self.preset]

"""The generation config: every knob with its default in one place (typed, validated), from YAML + overrides.

Every number is checked where it enters: each float finite (``allow_inf_nan=False`` on every section) and in
its range, so a config that loads cannot fail later on a value, after files are written.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal, Optional, Union

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from pegasus_gen.errors import PegasusError
from pegasus_gen.io.files import parse_yaml
from pegasus_gen.render.shadows import ShadowParams

CONFIG_FILE = "pegasus_config.yaml"  # a dataset's record of the config it was made with (and so of its size)
UINT16_MAX = 65535  # the largest value of a depth PNG
# a depth PNG must store depths up to this many times the farthest camera distance: the objects and the scene
# behind them up to as far again
DEPTH_REACH = 2.0


class _Strict(BaseModel):
    """A config section: unknown keys refused, every float finite."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class CameraConfig(_Strict):
    """Pinhole intrinsics: fx/fy in pixels, or a horizontal field of view; principal point default: centre."""

    width: int = Field(default=640, ge=16, le=8192)
    height: int = Field(default=480, ge=16, le=8192)
    fov_deg: float = Field(default=60.0, gt=1.0, lt=179.0)
    fx: Optional[float] = Field(default=None, gt=0)
    fy: Optional[float] = Field(default=None, gt=0)
    cx: Optional[float] = None
    cy: Optional[float] = None

    @model_validator(mode="after")
    def _intrinsics(self):
        for name, f, size in (("fx", self.fx, self.width), ("fy", self.fy, self.height)):
            if f is not None and not 1.0 < math.degrees(2 * math.atan(size / 2 / f)) < 179.0:
                raise ValueError(f"{name} must give a field of view between 1 and 179 degrees: "
                                 f"{size / 2 / math.tan(math.radians(89.5)):.3g} < {name} < "
                                 f"{size / 2 / math.tan(math.radians(0.5)):.6g} px at {size} px")
        for name, c, size in (("cx", self.cx, self.width), ("cy", self.cy, self.height)):
            if c is not None and not 0 <= c <= size:
                raise ValueError(f"{name} must lie in the image: 0 <= {name} <= {size} px")
        return self


class TrajectoryConfig(_Strict):
    """Random key poses on a shell around the objects, interpolated (SLERP + linear) into frames."""

    distance: tuple[float, float] = (0.45, 0.8)  # m from the objects' centre
    elevation_deg: tuple[float, float] = (25.0, 65.0)
    azimuth_span_deg: float = Field(default=120.0, ge=0.0, le=360.0)
    key_poses: int = Field(default=3, ge=1, le=100)
    jitter: float = Field(default=0.03, ge=0.0, le=1.0)  # m of random aim offset
    # key poses are redrawn until the environment fills this fraction of the view (0: accept any)
    min_view_coverage: float = Field(default=0.97, ge=0.0, le=1.0)
    # share of the scenes whose key poses are chosen (of all their tries) to show the labelled objects nearest to
    # half hidden by the other objects (trajectory.Hiding): occluded views, as on a cluttered desk
    occlusion: float = Field(default=0.0, ge=0.0, le=1.0)

    @model_validator(mode="after")
    def _ranges(self):
        if not 0 < self.distance[0] <= self.distance[1] <= 20:
            raise ValueError("distance must be (min, max) with 0 < min <= max <= 20 (m)")
        if not -90 <= self.elevation_deg[0] <= self.elevation_deg[1] <= 90:
            raise ValueError("elevation_deg must be (min, max) within -90..90")
        return self


class ObjectSpec(_Strict):
    """An object asset (name or obj_id) and how many instances of it a scene holds (inclusive range)."""

    asset: Union[str, int]
    count: tuple[int, int] = (0, 1)

    @model_validator(mode="after")
    def _count(self):
        if not 0 <= self.count[0] <= self.count[1] <= 20:
            raise ValueError("count must be (min, max) with 0 <= min <= max <= 20")
        return self


class ShadowConfig(_Strict):
    """Contact shadows and ambient occlusion (``pegasus_gen.render.shadows``): splats near placed objects
    darkened by the share of the sky (and of an optional key light) the objects hide."""

    enabled: bool = True
    # share of the scenes shaded (drawn per scene): a network that never sees an object without its rendered
    # contact shadow reads the shadow as part of the object (docs/TRAINING.md, run DEMO-S)
    share: float = Field(default=1.0, ge=0.0, le=1.0)
    radius: float = Field(default=0.1, gt=0.0, le=2.0)  # m: occluders farther than this along a sky ray do not count
    strength: float = Field(default=0.6, ge=0.0, le=1.0)  # colour x (1 - strength) at full occlusion
    rays: int = Field(default=16, ge=1, le=1024)  # sky rays per splat (spun per splat: overlapping splats average)
    light_direction: Optional[tuple[float, float, float]] = None  # world, towards a key light; None: sky only
    light_weight: float = Field(default=0.5, ge=0.0, le=1.0)  # share of the key light in the darkening
    light_cone_deg: float = Field(default=8.0, ge=0.0, lt=90.0)  # the light's cone: soft shadow edges
    light_rays: int = Field(default=8, ge=1, le=256)

    def params(self) -> ShadowParams:
        """The renderer's parameters."""
        return ShadowParams(**self.model_dump(exclude={"enabled", "share"}))

    @model_validator(mode="after")
    def _light(self):
        if self.light_direction is not None and not 0 < sum(v * v for v in self.light_direction) < float("inf"):
            raise ValueError("light_direction must be a non-zero vector")
        return self


def _range(lo: float, hi: float):
    """A (min, max) pair field with min <= max, both within [lo, hi]."""
    def check(value):
        if not lo <= value[0] <= value[1] <= hi:
            raise ValueError(f"must be (min, max) with {lo:g} <= min <= max <= {hi:g}")
        return value
    return AfterValidator(check)


Range = tuple[float, float]


class AppearanceConfig(_Strict):
    """Appearance and sensor randomisation, drawn per scene (objects, environment) and per frame (camera),
    from the scene's seed: each value is drawn uniformly from its (min, max)."""

    enabled: bool = True
    object_gain: Annotated[Range, _range(0.1, 10.0)] = (0.85, 1.15)  # per instance and channel
    object_hue_deg: float = Field(default=8.0, ge=0.0, le=180.0)  # per instance, hue turned by up to this
    environment_tint: Annotated[Range, _range(0.1, 10.0)] = (0.9, 1.1)  # per scene and channel
    # share of scenes whose environment is repainted with a random procedural texture (stripes, checks or
    # blobs, features of texture_period m), blended over the scan's colour by a weight from texture_weight
    retexture: float = Field(default=0.0, ge=0.0, le=1.0)
    texture_period: Annotated[Range, _range(0.001, 10.0)] = (0.02, 0.15)
    texture_weight: Annotated[Range, _range(0.0, 1.0)] = (0.5, 1.0)
    # share of the repainted environments whose texture takes one or two of the scene's objects' own colours (a
    # surface the objects blend into, as a photo's object on a cloth of its colour) instead of random ones
    texture_object_colours: float = Field(default=0.0, ge=0.0, le=1.0)
    # share of scenes whose objects (and distractors) are lit by a distant light from a random direction 20-90
    # degrees above the horizon: each splat's colour x (ambient + (1 - ambient) 1.5 max(0, n . light)), the
    # ambient share drawn from object_ambient (splats.colour.shade_lambert)
    object_light: float = Field(default=0.0, ge=0.0, le=1.0)
    object_ambient: Annotated[Range, _range(0.0, 1.0)] = (0.35, 0.75)
    # the lit scenes' highlights: white of strength drawn from object_specular added where a splat mirrors the light
    # towards the camera, strength * max(0, n . h)^shininess (Blinn-Phong, shininess drawn from object_shininess;
    # splats.colour.shade_specular), recomputed for every frame; (0, 0): none, as a scan's diffuse colours alone
    object_specular: Annotated[Range, _range(0.0, 2.0)] = (0.0, 0.0)
    object_shininess: Annotated[Range, _range(1.0, 1000.0)] = (8.0, 48.0)
    exposure_ev: Annotated[Range, _range(-10.0, 10.0)] = (-0.6, 0.4)  # per frame: gain 2^ev
    white_balance: Annotated[Range, _range(0.1, 10.0)] = (0.9, 1.1)  # per frame, red and blue gains (green 1)
    gamma: Annotated[Range, _range(0.1, 10.0)] = (0.85, 1.2)  # per frame: out = in^(1/gamma)
    shot_noise: Annotated[Range, _range(0.0, 1.0)] = (0.0, 0.03)  # std at value 1 (std = this * sqrt(value))
    read_noise: Annotated[Range, _range(0.0, 1.0)] = (0.0, 0.01)
    defocus_px: Annotated[Range, _range(0.0, 50.0)] = (0.0, 1.2)  # blur disc radius
    # fraction of the frame interval the shutter is open: a streak of the image motion per frame x this
    shutter: Annotated[Range, _range(0.0, 1.0)] = (0.0, 0.3)
    jpg_quality: Annotated[tuple[int, int], _range(1, 100)] = (70, 95)  # per frame (image_format jpg)


class DistractorConfig(_Strict):
    """Procedural clutter dropped with the objects in each scene, never labelled
    (``pegasus_gen.dataset.distractors``)."""

    count: tuple[int, int] = (1, 3)  # per scene, inclusive range
    size: Annotated[Range, _range(0.01, 1.0)] = (0.04, 0.14)  # m, the largest extent
    # share of the distractors painted in one or two colours of the scene's objects' splats instead of random ones:
    # hard negatives, the objects' colour without their shape
    object_colours: float = Field(default=0.0, ge=0.0, le=1.0)

    @model_validator(mode="after")
    def _count(self):
        if not 0 <= self.count[0] <= self.count[1] <= 20:
            raise ValueError("count must be (min, max) with 0 <= min <= max <= 20")
        return self


def _demo_objects() -> list[ObjectSpec]:
    return [ObjectSpec(asset=i, count=(0, 1)) for i in range(1, 9)]


class GenerateConfig(_Strict):
    """Everything `pegasus generate` needs; defaults make a small dataset from the demo library."""

    output: Path = Path("out/dataset")
    library: Optional[Path] = None  # default: $PEGASUS_ASSETS or ~/.cache/pegasus/assets
    environments: list[str] = Field(default_factory=lambda: ["wooden_table", "tiled_floor", "store_shelf"],
                                    min_length=1)
    objects: list[ObjectSpec] = Field(default_factory=_demo_objects, min_length=1)
    min_objects: int = Field(default=3, ge=1, le=50)  # at least this many instances per scene
    scenes: int = Field(default=4, ge=1, le=100_000)
    frames_per_scene: int = Field(default=10, ge=1, le=1000)
    dynamic: bool = False  # record the objects while they fall instead of after they rest
    fps: float = Field(default=30.0, gt=0, le=1000)  # camera frame rate of dynamic scenes
    camera: CameraConfig = Field(default_factory=CameraConfig)
    shadows: ShadowConfig = Field(default_factory=ShadowConfig)
    appearance: AppearanceConfig = Field(default_factory=AppearanceConfig)
    distractors: DistractorConfig = Field(default_factory=DistractorConfig)
    trajectory: TrajectoryConfig = Field(default_factory=TrajectoryConfig)
    # share of the objects (not the distractors) spawned standing as their asset stands (z up, any turn about z,
    # leaning at most 10 degrees) instead of in a uniformly random orientation; all of them then drop and settle
    upright: float = Field(default=0.0, ge=0.0, le=1.0)
    # share of the scenes whose objects and distractors are dropped packed together (a square of the drop region
    # of their bounding circles' area, physics.packed_region): they come to rest touching and stacked, and hide
    # one another
    packed: float = Field(default=0.0, ge=0.0, le=1.0)
    device: Literal["auto", "cpu", "cuda"] = "auto"
    # render with Mip-Splatting's 2D filter (render()'s antialiased): the flat splats of imported meshes, seen
    # edge-on at a silhouette, then widen it less (an LM-O object's render at 32 px across: 7.4 % larger than its
    # mesh classic, 2.6 % antialiased)
    antialiased: bool = False
    image_format: Literal["jpg", "png"] = "jpg"
    jpg_quality: int = Field(default=95, ge=1, le=100)
    # png value * depth_scale = mm (BOP PBR uses 0.1, BOP's real captures 1.0); large enough to store the
    # scene's depths (see _depth_range)
    depth_scale: float = Field(default=0.1, gt=0, le=1.0)
    visib_delta: float = Field(default=0.015, gt=0, le=0.1)  # m, BOP's visibility tolerance
    dope_json: bool = False
    # BOP split folder; "test" also writes test_targets_bop19.json (the instances at visib_fract >= 0.1)
    split: Literal["train_pbr", "val", "test"] = "train_pbr"
    # the dataset's name in bop_toolkit (its folder under the toolkit's datasets_path); COCO's supercategory
    dataset_name: str = Field(default="pegasus", pattern=r"^[A-Za-z0-9_-]+$")
    seed: int = Field(default=0, ge=0)
    workers: int = Field(default=1, ge=1, le=256)
    # run scenes as Ray tasks: "auto" (the running cluster), "local" (a private instance with `workers` CPUs)
    # or a cluster address (HEAD:6379, ray://HEAD:10001); None: worker processes on this machine
    ray: Optional[str] = Field(default=None, min_length=1)

    @field_validator("depth_scale")
    @classmethod
    def _depth_range(cls, depth_scale: float, info: ValidationInfo) -> float:
        """A uint16 depth PNG stores up to 65535 x ``depth_scale`` mm: that must reach DEPTH_REACH x the
        trajectory's farthest camera distance, or the scene's depth would be clipped."""
        trajectory = info.data.get("trajectory")
        if trajectory is not None:
            needed_m, stored_m = DEPTH_REACH * trajectory.distance[1], UINT16_MAX * depth_scale / 1000
            if stored_m < needed_m:
                raise ValueError(f"{depth_scale:g} mm per unit stores depths up to {stored_m:.3g} m "
                                 f"in a uint16 PNG; the scene needs {needed_m:.3g} m ({DEPTH_REACH:g} x "
                                 f"trajectory.distance max): use depth_scale >= "
                                 f"{math.ceil(needed_m * 1e6 / UINT16_MAX) / 1000:g}")
        return depth_scale


def _set(tree: dict, dotted: str, value) -> None:
    keys = dotted.split(".")
    node = tree
    for key in keys[:-1]:
        node = node.setdefault(key, {})
        if not isinstance(node, dict):
            raise PegasusError(f"override {dotted}: {key} is not a section")
    node[keys[-1]] = value


def load_config(path: str | Path | None = None, overrides: list[str] = ()) -> GenerateConfig:
    """The config from a YAML file (optional) with ``key.sub=value`` overrides (values parsed as YAML)."""
    tree: dict = {}
    if path is not None:
        try:
            text = Path(path).read_text()
        except OSError as exc:
            raise PegasusError(f"{path}: cannot read config ({exc.strerror or exc})") from None
        tree = parse_yaml(text, str(path)) or {}
        if not isinstance(tree, dict):
            raise PegasusError(f"{path}: the config must be a mapping of keys to values")
    for item in overrides:
        if "=" not in item:
            raise PegasusError(f"override {item!r}: expected key=value (e.g. camera.width=320)")
        key, value = item.split("=", 1)
        _set(tree, key.strip(), parse_yaml(value, f"override {item!r}"))
    try:
        return GenerateConfig.model_validate(tree)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "(top level)"
        source = f"{path}: " if path is not None else ""
        raise PegasusError(f"{source}config key {where}: {first['msg']}") from None

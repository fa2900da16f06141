"""Flags that several commands share, each defined once, and what they resolve to."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pegasus_gen.errors import PegasusError
from pegasus_gen.splats.ply import MAX_COORDINATE

DEVICES = ("auto", "cpu", "cuda")


def add_library(p) -> None:
    """--library: the asset library folder."""
    p.add_argument("--library", help="asset library folder (default: $PEGASUS_ASSETS or ~/.cache/pegasus/assets)")


def add_device(p, default: str = "auto", what: str = "") -> None:
    """--device auto|cpu|cuda."""
    p.add_argument("--device", choices=DEVICES, default=default, help=what or None)


def add_seed(p) -> None:
    """--seed: the run's random seed."""
    p.add_argument("--seed", type=int, default=0)


def add_host(p) -> None:
    """--host: the simulated controller's loopback address."""
    p.add_argument("--host", default="127.0.0.1", help="loopback address for the simulated controller")


def library(args):
    """The AssetLibrary named by --library (or the default one)."""
    from pegasus_gen.assets.library import AssetLibrary

    return AssetLibrary(args.library)


def add_camera(p) -> None:
    """Pinhole camera flags: image size, field of view or focal lengths, principal point, eye/target or framing."""
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--fov", type=float, default=60.0, help="horizontal field of view, degrees (unless --fx)")
    p.add_argument("--fx", type=float, help="focal length in pixels (fy defaults to fx)")
    p.add_argument("--fy", type=float)
    p.add_argument("--cx", type=float, help="principal point (default: image centre)")
    p.add_argument("--cy", type=float)
    p.add_argument("--eye", type=float, nargs=3, metavar=("X", "Y", "Z"), help="camera position (world, m)")
    p.add_argument("--target", type=float, nargs=3, metavar=("X", "Y", "Z"), help="point looked at")
    p.add_argument("--azimuth", type=float, default=-60.0, help="auto-framing azimuth, degrees")
    p.add_argument("--elevation", type=float, default=35.0, help="auto-framing elevation, degrees")


def check_camera(args) -> None:
    """Refuse impossible camera flags (PegasusError, one line) before any work: a positive image size whose
    render fits in memory, a field of view in (0, 180) degrees, focal lengths finite and positive, principal
    point, --eye and --target finite and within MAX_COORDINATE metres."""
    from pegasus_gen.render.renderer import check_image_memory

    if args.width <= 0 or args.height <= 0:
        raise PegasusError(f"--width and --height must be positive, got {args.width} x {args.height}")
    check_image_memory(args.width, args.height)
    if not 0.0 < args.fov < 180.0:
        raise PegasusError(f"--fov must be between 0 and 180 degrees (exclusive), got {args.fov}")
    for name in ("fx", "fy"):
        value = getattr(args, name)
        if value is not None and not (np.isfinite(value) and value > 0):
            raise PegasusError(f"--{name} must be a positive number of pixels, got {value}")
    for name in ("cx", "cy"):
        value = getattr(args, name)
        if value is not None and not np.isfinite(value):
            raise PegasusError(f"--{name} must be a finite number of pixels, got {value}")
    for name in ("eye", "target"):
        value = getattr(args, name)
        if value is not None and not np.all(np.abs(value) <= MAX_COORDINATE):
            raise PegasusError(f"--{name} must be 3 finite numbers within {MAX_COORDINATE:g} m, got {value}")


def camera(args, points: np.ndarray):
    """(K [3, 3], T_cam_world [4, 4]) from the camera flags; without --eye the points [N, 3] are framed."""
    from pegasus_gen.geometry.cameras import frame_points, intrinsics, look_at

    K = intrinsics(args.width, args.height, args.fov, args.fx, args.fy, args.cx, args.cy)
    if args.eye is not None:
        target = args.target if args.target is not None else np.median(points, axis=0)
        if np.array_equal(np.asarray(args.eye, np.float64), target):
            raise PegasusError(f"--eye {args.eye} is the point looked at (--target, or the splats' median): "
                               "the camera needs a direction")
        T = look_at(args.eye, target)
    else:
        T = frame_points(points, K, args.width, args.height, args.azimuth, args.elevation)
    return K, T


def output_folder(path, flag: str = "--out") -> Path:
    """The output folder named by ``flag``, refused (PegasusError) before any work when it, or the nearest
    existing folder above it, is a file."""
    path = Path(path)
    existing = next((p for p in (path, *path.parents) if p.exists()), None)
    if existing is not None and not existing.is_dir():
        where = "" if existing == path else f": {existing}"
        raise PegasusError(f"{flag} {path}{where} is a file, not a folder")
    return path


def write_render_outputs(out_dir: Path, out) -> list[Path]:
    """rgb, depth (mm, and coloured), labels and an overview sheet of a RenderOutput as PNGs in out_dir."""
    from pegasus_gen.io import images

    depth_mm = np.clip(np.round(out.depth * 1000.0), 0, 65535).astype(np.uint16)
    written = [
        images.write_image(out_dir / "rgb.png", images.rgb_to_uint8(out.rgb)),
        images.write_image(out_dir / "depth_mm.png", depth_mm),
        images.write_image(out_dir / "depth_vis.png", images.colorize_depth(out.depth)),
        images.write_image(out_dir / "labels.png", images.colorize_labels(out.label)),
    ]
    sheet = np.concatenate([images.rgb_to_uint8(out.rgb), images.colorize_depth(out.depth),
                            images.colorize_labels(out.label)], axis=1)
    written.append(images.write_image(out_dir / "overview.png", sheet))
    return written


def _flag_kwargs(field) -> dict:
    """argparse keywords for a pydantic field: type, default or required, help, choices (Literal), nargs
    (tuple: its length, list: one or more), store_true (bool defaulting to False)."""
    import types
    import typing

    kind = field.annotation
    if typing.get_origin(kind) in (typing.Union, types.UnionType):  # Optional[X]: X
        kind = next(a for a in typing.get_args(kind) if a is not type(None))
    kwargs = {"help": field.description}
    if field.is_required():
        kwargs["required"] = True
    else:
        kwargs["default"] = field.get_default(call_default_factory=True)
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if kind is bool:
        kwargs["action"] = "store_true"
    elif origin is typing.Literal:
        kwargs.update(choices=args, type=type(args[0]))
    elif origin is tuple:
        kwargs.update(type=args[0], nargs="+" if args[-1] is Ellipsis else len(args))
    elif origin is list:
        kwargs.update(type=args[0], nargs="+")
    else:
        kwargs["type"] = kind
    return kwargs


def add_config_flags(parser, model, fields, **flags: dict) -> None:
    """One flag per named field of a pydantic ``model``: ``--field-name`` (``--no-field-name`` for a bool that
    defaults to True), help from the field's description. ``flags[name]`` replaces argparse keywords of one
    flag (e.g. a metavar, or ``action="append"``)."""
    for name in fields:
        kwargs = {**_flag_kwargs(model.model_fields[name]), **flags.get(name, {})}
        flag = "--" + name.replace("_", "-")
        if kwargs.get("action") == "store_true" and kwargs.get("default") is True:
            flag, kwargs["action"] = "--no-" + name.replace("_", "-"), "store_false"
            kwargs["help"] = f"turn off {kwargs['help']}" if kwargs["help"] else None
        if kwargs.get("action") in ("store_true", "store_false"):
            kwargs.pop("type", None)
        parser.add_argument(flag, dest=name, **kwargs)


def config_from_args(model, args, **extra):
    """``model`` built from the parsed ``args`` of the same names (and ``extra`` values); a ValidationError
    becomes one PegasusError line naming the flag."""
    from pydantic import ValidationError

    values = {name: getattr(args, name) for name in model.model_fields if hasattr(args, name)}
    try:
        return model(**{**values, **extra})
    except ValidationError as exc:
        first = exc.errors()[0]
        message = str(first["ctx"]["error"]) if first["type"] == "value_error" else first["msg"]
        if not first["loc"]:
            raise PegasusError(message) from None
        name = str(first["loc"][0])
        where = "--" + name.replace("_", "-") if name in values and name not in extra else name
        got = "" if first["type"] == "missing" else f" (got {first['input']!r})"
        raise PegasusError(f"{where}: {message}{got}") from None

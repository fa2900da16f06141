"""The refinement against the RGB image (``dope_training.refine_rgb``) started from the ground truth: how much of
the truth it keeps, and how much of a start's error it takes away, on any BOP split with ground truth (real photos
or generated frames) and without a network.

Usage: python benchmarks/refine_rgb.py --data DIR [--split test] --objects ID[,ID...] [--min-visibility 0.5]
       [--max-images N] [--distance-error 0.03] [--rotation-error-deg 10] [--aside-error-m 0.005] [--seed 0]
       [--set key=value ...] [--zoom ID=PATH ...] [--out FILE.json]

Each instance of the objects seen at ``--min-visibility`` or more is refined from three starts, each with the
dataset's model of the object (``models/``, as ``pegasus eval --refine-rgb`` refines):

- ``truth``: the true pose itself (a refinement that reads the image exactly leaves it there);
- ``distance``: the truth moved along its ray by the factor exp(e), e ~ N(0, ``--distance-error``);
- ``estimate``: that, turned about a random axis by N(0, ``--rotation-error-deg``) per axis and moved aside by
  N(0, ``--aside-error-m``) in the image plane: an error of the size a network's estimate has.

Per object and start it prints the share within 0.1 d (ADD, or ADD-S for a symmetric object; 10 % of the
diameter) before and after, the share whose distance alone is within 0.1 d, the refined distance's median ratio to
the true one and its quartiles, and for ``distance`` the share of the start's distance error that is left (the
slope of log(refined / true distance) on log(start / true distance): 0 when the refinement reads the distance from
the image whatever the start, 1 when it keeps the start's). ``--set`` changes ``RgbRefineParams`` fields (a variant
of the refinement to measure, e.g. ``--set lines=240 half_length_px=[24,12,6]``); ``--out`` writes the figures as
JSON.

``--zoom ID=PATH`` (a zoom network of that object, ``pegasus train-zoom``) measures the zoomed second look from the
same starts too: each start moved by the zoom network alone (``zoom``), and by the zoom network and then the
refinement (``zoom+rgb``, as ``pegasus eval --zoom --refine-rgb`` takes an estimate), one line per start and way;
without it only the refinement (``rgb``).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, fields
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from dope_training.evaluate import model_points
from dope_training.looks import load as load_zoom
from dope_training.refine_rgb import RgbRefineParams, decimated, refine_rgb
from dope_training.train_config import parse_options
from pegasus_gen.errors import PegasusError
from pegasus_gen.formats.bop import bop_frames, models_info, read_model
from pegasus_gen.geometry.pose_error import add_error, adds_error
from pegasus_gen.io import images
from pegasus_gen.io.files import write_atomic

STARTS = ("truth", "distance", "estimate")
WAYS = ("rgb", "zoom", "zoom+rgb")  # the refinement alone; the zoom network alone; the zoom, then the refinement


def start_poses(T: np.ndarray, rng: np.random.Generator, distance_error: float, rotation_error_deg: float,
                aside_error_m: float) -> dict[str, np.ndarray]:
    """The three starts (``STARTS``) [4, 4] for a true T_cam_obj [4, 4] (m)."""
    moved = T.copy()
    moved[:3, 3] *= np.exp(rng.normal(0.0, distance_error))
    estimate = moved.copy()
    turn = Rotation.from_rotvec(np.radians(rng.normal(0.0, rotation_error_deg, 3)))
    estimate[:3, :3] = turn.as_matrix() @ T[:3, :3]
    estimate[:2, 3] += rng.normal(0.0, aside_error_m, 2)
    return {"truth": T.copy(), "distance": moved, "estimate": estimate}


def refine_params(options: dict) -> RgbRefineParams:
    """RgbRefineParams with ``options`` ({field: value}; lists become tuples) on its defaults; a PegasusError naming
    an unknown field."""
    known = {f.name for f in fields(RgbRefineParams)}
    if unknown := sorted(set(options) - known):
        raise PegasusError(f"--set {unknown[0]}: not an RgbRefineParams field ({', '.join(sorted(known))})")
    return RgbRefineParams(**{k: tuple(v) if isinstance(v, list) else v for k, v in options.items()})


def figures(rows: list[dict], diameter_m: float) -> dict:
    """The figures of one object and start from its rows (``error_m``, ``start_error_m``, ``ratio``,
    ``start_ratio``, ``distance_m``)."""
    error = np.array([r["error_m"] for r in rows])
    start = np.array([r["start_error_m"] for r in rows])
    ratio = np.array([r["ratio"] for r in rows])
    start_ratio = np.array([r["start_ratio"] for r in rows])
    distance = np.array([r["distance_m"] for r in rows])
    out = {"instances": len(rows), "start_within_0_1d": float(np.mean(start < 0.1 * diameter_m)),
           "within_0_1d": float(np.mean(error < 0.1 * diameter_m)),
           "distance_within_0_1d": float(np.mean(np.abs(ratio - 1) * distance < 0.1 * diameter_m)),
           "ratio_quartiles": np.percentile(ratio, [25, 50, 75]).round(4).tolist()}
    if np.ptp(np.log(start_ratio)) > 1e-6:
        out["distance_error_left"] = float(np.polyfit(np.log(start_ratio), np.log(ratio), 1)[0])
    return out


def zooms(options: list[str], ids: list[int]) -> dict:
    """The ``--zoom ID=PATH`` networks by obj_id; a PegasusError for a malformed one, an object not in ``ids`` or a
    network of another object."""
    out = {}
    for option in options:
        key, sep, path = option.partition("=")
        if not sep or not key.strip().isdigit() or int(key) not in ids:
            raise PegasusError(f"--zoom {option!r}: ID=PATH with ID one of --objects ({', '.join(map(str, ids))})")
        obj_id = int(key)
        out[obj_id] = load_zoom(path)
        if out[obj_id].obj_id != obj_id:
            raise PegasusError(f"--zoom {option!r}: {path} is a zoom network of obj_id {out[obj_id].obj_id}")
    return out


def describe(obj_id: int, start: str, f: dict, way: str = "rgb") -> str:
    """One object's ``figures`` from one start, taken one way (``WAYS``), as the line the benchmark prints."""
    q = f["ratio_quartiles"]
    left = f", distance error left {f['distance_error_left']:.2f}" if "distance_error_left" in f else ""
    how = "" if way == "rgb" else f" ({way})"
    return (f"obj {obj_id} from the {start}{how}: {f['instances']} instances, within 0.1 d "
            f"{f['start_within_0_1d']:.2f} -> {f['within_0_1d']:.2f}, distance alone {f['distance_within_0_1d']:.2f}, "
            f"distance x{q[1]:.3f} (quartiles {q[0]:.3f}-{q[2]:.3f}){left}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", required=True, help="BOP dataset root with ground truth")
    parser.add_argument("--split", default="test")
    parser.add_argument("--objects", required=True, help="obj_ids, comma-separated")
    parser.add_argument("--min-visibility", type=float, default=0.5)
    parser.add_argument("--max-images", type=int, default=None, help="images per scene (default: all)")
    parser.add_argument("--distance-error", type=float, default=0.03, help="standard deviation of log distance")
    parser.add_argument("--rotation-error-deg", type=float, default=10.0, help="per axis, degrees")
    parser.add_argument("--aside-error-m", type=float, default=0.005, help="per image axis, metres")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", nargs="*", default=[], help="RgbRefineParams fields (key=value)")
    parser.add_argument("--zoom", nargs="*", default=[], help="zoom networks (ID=PATH) to measure as well")
    parser.add_argument("--out", type=Path, default=None, help="JSON file for the figures")
    args = parser.parse_args()
    root = Path(args.data)
    try:
        ids = [int(i) for i in args.objects.split(",")]
    except ValueError:
        raise PegasusError(f"--objects {args.objects!r}: comma-separated obj_ids") from None
    errors = (args.distance_error, args.rotation_error_deg, args.aside_error_m)
    if not 0 <= args.min_visibility <= 1 or min(errors) < 0 or (args.max_images is not None and args.max_images < 1):
        raise PegasusError("--min-visibility in 0..1, the errors >= 0 and --max-images >= 1")
    params = refine_params(parse_options(args.set))
    zoom = zooms(args.zoom, ids)
    info = models_info(root)
    if missing := [i for i in ids if i not in info or info[i].diameter is None]:
        raise PegasusError(f"{root}: models_info.json has no diameter for obj_id {missing[0]}")
    meshes = {}
    for i in ids:
        model = read_model(root, i)
        meshes[i] = decimated(model.vertices, model.faces)
    points = {i: model_points(root, i) for i in ids}
    rng = np.random.default_rng(args.seed)
    ways = {i: WAYS if i in zoom else WAYS[:1] for i in ids}
    rows: dict[tuple[int, str, str], list[dict]] = {(i, s, w): [] for i in ids for s in STARTS for w in ways[i]}
    for frame in tqdm(list(bop_frames(root / args.split, args.max_images)), desc="refine_rgb", unit="img"):
        mine = [t for t in frame.instances
                if t.obj_id in ids and (t.visib_fract is None or t.visib_fract >= args.min_visibility)]
        image = images.read_rgb(frame.image) if mine else None
        for truth in mine:
            error = adds_error if info[truth.obj_id].symmetric else add_error
            poses = start_poses(truth.T, rng, args.distance_error, args.rotation_error_deg, args.aside_error_m)
            distance = float(np.linalg.norm(truth.T[:3, 3]))
            for name, T in poses.items():
                taken = {"rgb": refine_rgb(image, frame.K, T, *meshes[truth.obj_id], params).T}
                if truth.obj_id in zoom:
                    taken["zoom"] = zoom[truth.obj_id].refine(image, frame.K, T)
                    taken["zoom+rgb"] = refine_rgb(image, frame.K, taken["zoom"], *meshes[truth.obj_id], params).T
                for way, refined in taken.items():
                    rows[truth.obj_id, name, way].append({
                        "error_m": error(points[truth.obj_id], refined, truth.T),
                        "start_error_m": error(points[truth.obj_id], T, truth.T), "distance_m": distance,
                        "ratio": float(np.linalg.norm(refined[:3, 3])) / distance,
                        "start_ratio": float(np.linalg.norm(T[:3, 3])) / distance, "visib_fract": truth.visib_fract})
    out = {"data": str(root), "split": args.split, "params": asdict(params), "min_visibility": args.min_visibility,
           "distance_error": args.distance_error, "rotation_error_deg": args.rotation_error_deg,
           "aside_error_m": args.aside_error_m, "seed": args.seed, "zoom": args.zoom, "objects": {}}
    for i in ids:
        if not rows[i, STARTS[0], WAYS[0]]:
            print(f"obj {i}: no instance seen at {args.min_visibility} or more")
            continue
        figs = {w: {s: figures(rows[i, s, w], info[i].diameter) for s in STARTS} for w in ways[i]}
        # an object's figures: {start: ...} of the refinement, and with --zoom {"zoom": {start: ...}, "zoom+rgb": ...}
        out["objects"][str(i)] = {**figs[WAYS[0]], **{w: figs[w] for w in ways[i][1:]}}
        for w in ways[i]:
            for s in STARTS:
                print(describe(i, s, figs[w][s], w))
    if args.out is not None:
        out["rows"] = {f"{i} {s}" + ("" if w == WAYS[0] else f" {w}"): r for (i, s, w), r in rows.items()}
        write_atomic(args.out, lambda f: f.write(json.dumps(out, indent=1).encode()))
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except PegasusError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)

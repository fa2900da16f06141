"""From a real BOP dataset to a table: generated training data, one DOPE network per object, scored on the
dataset's real photos (DOPE alone).

Usage: python benchmarks/real.py --real DIR [--split test] --objects ID[,ID...] [--frames 2400] [--epochs 20]
       [--variant light|pretrained] [--distance 0.4 1.4] [--max-images N] [--device auto|cpu|cuda] [--refine-rgb]
       [--zoom-epochs 8] [--no-zoom] [--no-outline] [--generate key=value ...] [--train key=value ...]
       [--zoom-train key=value ...] --out OUT

What it reads of DIR, and nothing else: ``models/obj_*.ply`` (mm, vertex colour: the objects, and the others as
clutter) and ``models/models_info.json`` (diameter), the split's ``scene_camera.json`` (the real camera's K) and
image size, and for scoring the split's ground truth. Steps, each with its time:

1. Library ``OUT/library``: the built-in environments (built in ``OUT/demo_library``), each object imported from
   its BOP model, and up to ``CLUTTER_MODELS`` of the dataset's other models.
2. One training dataset ``OUT/data`` for all the objects (``--frames`` frames, 2 per scene): every object in
   every scene (target and clutter of the others), each of the other models in half of the scenes, 3-8
   procedural distractors (half of them painted in the objects' colours; three quarters of the scenes packed
   together: ``PACKED``), the three built-in environments (half of the scenes repainted with a random texture),
   generate's shadows and appearance randomisation (each object's hue turned by up to ``OBJECT_HUE_DEG``; the
   objects of ``OBJECT_LIGHT`` of the scenes lit by a distant light from a random direction, with highlights of a
   strength in ``OBJECT_SPECULAR``),
   cameras ``--distance`` m from the objects at 20-75 degrees elevation, motion blur at most as long as 5 % of an
   8-frame scene's image motion per frame (``SHUTTER``), half of the objects dropped standing (``UPRIGHT``),
   rendered antialiased (the meshes' splats otherwise look larger than the objects: docs/TRAINING.md) at the
   recipe's network scale (``dope_training.recipe``) with the real camera's shape, and ``--generate`` overrides on
   top; and a synthetic held-out set (another seed, ``--held-out-frames`` frames of two per scene). A finished
   dataset in OUT is reused.
3. Per object a network (``--variant``) trained with the recipe and ``--train`` TrainConfig fields on top
   (``OUT/runs/obj_ID``; a finished run is reused, one cut short resumed), and its two zoom networks, second,
   zoomed-in looks at each estimate applied in turn: the offsets look (``dope_training.zoom``: moves its centre and
   distance; ``--zoom-epochs`` epochs and ``--zoom-train`` ZoomConfig fields on top, ``OUT/runs/obj_ID/zoom.pt``;
   ``--no-zoom``: none), then the outline look (``dope_training.outline``: the object's outline read pixel by pixel
   and the model's fitted to it; the same fields without rotation and view, ``OUT/runs/obj_ID/outline.pt``;
   ``--no-outline``: none); each reused when there and trained with the same fields (``zoom.txt`` and
   ``outline.txt`` record them).
4. Per object, with the zoom networks (each estimate scored by its detection score times the share of its outline
   that the image's colour edges support at the looks' pose): ``pegasus eval`` figures on the synthetic held-out
   set and on its photo-backed copy (``OUT/held_out_photos``: the same frames with the background photos that
   training keeps back, ``backgrounds.split_photos``, behind their labelled objects: real textures the network never
   saw), which set the score threshold (the lowest leaving ``recipe.HELD_OUT_FALSE_POSITIVES`` false positives per
   image and keeping ``recipe.HELD_OUT_KEEP_FOUND`` of the instances found, on both sets); then on the real split
   with it (``OUT/eval/obj_ID``, ``OUT/eval_synthetic/obj_ID`` and ``OUT/eval_photo_backed/obj_ID``: eval.json, the
   curve and the gallery of the worst images); with ``--refine-rgb`` then the same again with those poses refined
   against the images (``pegasus eval --refine-rgb``: the dataset's model's silhouette fitted to the image's colour
   edges, scored by belief x outline support there, its own score threshold set the same way; after the outline look
   it costs on generated frames, docs/TRAINING.md; one pass of inference gives both) in ``OUT/eval_rgb``,
   ``OUT/eval_synthetic_rgb`` and ``OUT/eval_photo_backed_rgb``. RGB alone, no depth.

Writes ``OUT/real.json`` (with each step's seconds and the minutes per object: its training and evaluation, and
its share of the library and the data), prints one line per object (with ``--refine-rgb`` one line ``real, without
the RGB refinement: ...`` for DOPE and its zoom networks) and ends with one line: ``real: mean ADD(-S) 0.1d recall
R, AUC A, false positives per image F over N objects``: the estimates from the RGB images alone (DOPE and its zoom
networks; with ``--refine-rgb`` and the refinement against the image).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from pydantic import ValidationError

from dope_training.backgrounds import load_photos, photo_backed, split_photos
from dope_training.checkpoint import load_checkpoint
from dope_training.evaluate import describe_found, evaluate, score_threshold, write_eval_report
from dope_training.infer import DopeModel
from dope_training.recipe import (
    HELD_OUT_FALSE_POSITIVES,
    HELD_OUT_KEEP_FOUND,
    VARIANT,
    RealCamera,
    network_focal,
    train_fields,
    training_camera,
)
from dope_training.train import train
from dope_training.train_config import TrainConfig, parse_options
from dope_training.zoom_config import ZoomConfig
from dope_training.zoom_train import train_zoom
from pegasus_gen.assets.demo_library import build_demo_library
from pegasus_gen.assets.importers import import_mesh
from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.cli.options import config_from_args
from pegasus_gen.dataset.config import load_config
from pegasus_gen.dataset.generate import generate
from pegasus_gen.errors import PegasusError
from pegasus_gen.formats.bop import bop_frames
from pegasus_gen.io.files import read_json

ENVIRONMENTS = "[wooden_table, tiled_floor, store_shelf]"
# few frames per scene, many scenes: a network trained on 100 scenes of 8 frames placed the duck within 8 degrees
# on its own training frames and 122 degrees off on held-out ones (run P): it learns the objects' placements, so
# each frame should show a placement of its own (run R: docs/TRAINING.md)
FRAMES_PER_SCENE = 2
# the detection score is set on them: 24 frames (run Q) left it to a handful of false positives, and 60 frames' rule
# alone moved the ape's photos by 1.14-1.61 false positives per image (four disjoint sets of 60: run II)
HELD_OUT_FRAMES = 240
# the shutter open for a small share of the frame interval: a scene's trajectory spans the same arc whatever its
# frame count, and at 8 frames per scene (median 46 px of image motion per frame at 640x480) generate's default
# (up to 30 %) smeared the object by up to 45 px, far more than a real camera's exposure does; the streak is kept
# at most 5 % of 8-frame scenes' motion per frame
SHUTTER = f"[0.0, {0.05 * (FRAMES_PER_SCENE - 1) / (8 - 1):.4f}]"
# half of the objects spawned standing as their model stands (z up: scans and BOP models are), half in a random
# orientation: dropped at random, an upright object rests on its side most of the time (the ape stood in 10 % of
# its frames) while the photos show it standing, and its network then mistook its orientation (by more than 90
# degrees in 64 % of the ape's photos found)
UPRIGHT = 0.5
# three quarters of the scenes dropped packed together with 3-8 distractors of up to 20 cm, so that the objects
# hide one another and the distractors crowd them as on a cluttered desk: scattered with 2-6 small distractors,
# 75 % of the generated instances were in full view, and the networks read partly hidden objects in the photos
# as too far (the ape's distance x1.49 under half visible, x1.008 in full view: run R, docs/TRAINING.md)
PACKED = 0.75
# half of the distractors painted in the objects' colours: packed scenes alone (run T) found more of the ape in the
# photos but fired three times as often on real clutter (5.1 false positives per photo), on things of its colour
DISTRACTORS = ["distractors.count=[3, 8]", "distractors.size=[0.05, 0.2]", "distractors.object_colours=0.5"]
# each object instance's hue turned by up to this (degrees) either way in every scene (generate's default: 8): a
# scan's colours are another camera's (the LM-O ape's model is red, the photos' ape orange-brown, their cat pink),
# and with each instance turned on its own the networks must tell the objects apart by shape (run LL in
# docs/TRAINING.md, the ape and the duck over two seeds: 0.54 -> 0.45 false positives per photo, AUC 0.374 -> 0.422)
OBJECT_HUE_DEG = 30
# the dataset's other models (DIR/models) dropped as clutter, each in half of the scenes, at most CLUTTER_MODELS of
# them (a seeded choice): real shapes and colours beside the targets, where the procedural distractors are boxes,
# cylinders and spheres (run W: the ape's and the duck's false positives per photo 2.67 -> 1.38 and 0.71 -> 0.39)
CLUTTER_MODELS = 4
# the objects (targets, clutter and distractors) of half of the scenes lit by a distant light from a random direction
# 20-90 degrees above the horizon (generate's appearance.object_light): a scan's vertex colours carry little of the
# shading a real object shows, and unlit, the networks read the LM-O duck as 2-3 % farther than it is in the photos
# over six runs; lit, x0.99 over two seeds (run RR in docs/TRAINING.md); the cat, lit, reads x0.95 (its photos' AUC
# 0.15 against 0.25 unlit): over the four LM-O objects lit and unlit tie (AUC 0.332 / 0.327, one seed each)
OBJECT_LIGHT = 0.5
# in those lit scenes the objects glossy: white highlights of the light, of a strength drawn in this range per scene
# (generate's appearance.object_specular, Blinn-Phong on smoothed splat normals): LM-O's objects are glossy plastic
# and glazed ceramic whose shape reads from their highlights, a scan's vertex colours are matte (runs YY and ZZ in
# docs/TRAINING.md: the holepuncher's photos' rotation within 0.1 d 0.27 -> 0.45, the duck's recall 0.132 -> 0.198,
# over the cat, the duck and the holepuncher recall 0.062 -> 0.092, AUC 0.315 -> 0.382, one seed each)
OBJECT_SPECULAR = "[0.1, 0.8]"


def real_camera(root: Path, split: str) -> RealCamera:
    """The split's camera: K of its first image and the image's size (one camera for the split)."""
    frame = next(bop_frames(root / split, 1), None)
    if frame is None:
        raise PegasusError(f"{root / split}: no images")
    image = cv2.imread(str(frame.image), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise PegasusError(f"{frame.image}: cannot read the image")
    height, width = image.shape[:2]
    return RealCamera(frame.K, width, height)


def object_infos(root: Path, info: dict, ids: list[int]) -> dict[int, dict]:
    """The entries of ``ids`` in ``info`` (``root``'s models_info.json); a clear error for a missing model or
    entry."""
    for i in ids:
        if str(i) not in info or not (root / "models" / f"obj_{i:06d}.ply").is_file():
            raise PegasusError(f"{root}/models: no obj_{i:06d}.ply with a models_info.json entry")
    return {i: info[str(i)] for i in ids}


def clutter_ids(root: Path, info: dict, ids: list[int], seed: int) -> list[int]:
    """obj_ids of the other models in ``root/models`` (a ply with an entry in ``info``, its models_info.json), at
    most ``CLUTTER_MODELS`` of them chosen with ``seed``, ascending."""
    others = sorted(int(k) for k in info
                    if int(k) not in ids and (root / "models" / f"obj_{int(k):06d}.ply").is_file())
    if len(others) > CLUTTER_MODELS:
        others = sorted(np.random.default_rng(seed).choice(others, CLUTTER_MODELS, replace=False).tolist())
    return others


def make_dataset(folder: Path, overrides: list[str]) -> Path:
    """The dataset of ``overrides`` in ``folder``, generated unless a finished one of the same overrides is
    there (one of others is refused)."""
    done, wanted = folder / "finished", "\n".join(overrides)
    if done.is_file() and done.read_text() != wanted:
        raise PegasusError(f"{folder} was generated with other settings; choose another --out")
    if not done.is_file():
        generate(load_config(None, [f"output={folder}", *overrides]), resume=folder.exists())
        done.write_text(wanted)
    return folder


def held_out_photos(folder: Path, held_out: Path, photo_folder: str | None, seed: int) -> Path:
    """``held_out``'s frames with the photos that training keeps back (``split_photos`` of ``photo_folder``,
    default scikit-image's) behind their objects, in ``folder``: made unless one of the same photos and seed is
    there (one of others is refused; ``folder``.txt records them)."""
    source = Path(photo_folder).resolve() if photo_folder else "scikit-image's photographs"
    record, wanted = folder.with_suffix(".txt"), f"photos={source}\nseed={seed}"
    if folder.is_dir() and (not record.is_file() or record.read_text() != wanted):
        raise PegasusError(f"{folder} was not made from {source} with seed {seed}; choose another --out")
    if not folder.is_dir():
        photos = split_photos(load_photos(photo_folder))[1]
        if not photos:
            raise PegasusError("the background photos are too few to hold one back for the held-out frames")
        record.write_text(wanted)  # before the copy, which appears whole or not at all
        photo_backed(held_out, "train_pbr", folder, photos, seed=seed)
    return folder


def trained_zoom(zoom: Path, cfg: ZoomConfig) -> Path:
    """The zoom network ``zoom`` of ``cfg``, trained unless one of the same fields is there (one of others is
    refused; ``zoom``.txt records them; the checkpoint is written when its training ends: one there is
    finished; a field the record lacks, newer than it, takes its default)."""
    record = zoom.with_suffix(".txt")
    try:
        same = not record.is_file() or ZoomConfig.model_validate_json(record.read_text()) == cfg
    except ValidationError:  # not a record of ZoomConfig's fields
        same = False
    if zoom.is_file() and not same:
        raise PegasusError(f"{zoom} was trained with other fields ({record}); remove it or choose another --out")
    if not zoom.is_file():
        train_zoom(cfg)
        record.write_text(cfg.model_dump_json(indent=1))
    return zoom


def figures(report: dict) -> dict:
    """The figures of one ``evaluate`` report that the table shows."""
    r, top = report["result"], report.get("top_n")
    return {"metric": report["metric"], "recall_0_1d": round(r["recall_0_1d"], 4), "auc": round(r["auc_0_10cm"], 4),
            "false_positives_per_image": round(report["false_positives_per_image"], 3),
            "instances": report["instances"], "misses": report["misses"], "images": report["images"],
            "min_score": report["min_score"], "found_poses": report["found_poses"],
            "top_n": top and {"recall_0_1d": round(top["result"]["recall_0_1d"], 4),
                              "auc": round(top["result"]["auc_0_10cm"], 4),
                              "off_target_per_image": round(top["off_target_per_image"], 3),
                              "instances": top["instances"], "misses": top["misses"]}}


def scored(model: DopeModel, held_out: tuple[Path, Path], root: Path, split: str, max_images: int | None,
           out: dict[str, tuple[Path, Path, Path]], refine_rgb: bool) -> dict[str, tuple[dict, dict, dict]]:
    """Figures (``figures``) on the synthetic held-out set, on its photo-backed copy and on the real split, whose
    detection score is the higher of the two the held-out sets calibrate (``score_threshold``: each holds
    negatives the other lacks, the rendered distractors and unseen photos); per pipeline: ``""`` the poses of DOPE
    and its zoom, with ``refine_rgb`` also ``"_rgb"`` those refined against the images (one pass gives both, each
    with its own detection score); the reports written to ``out[pipeline]`` (held-out, photo-backed, real folders:
    ``write_eval_report``)."""
    def pipelines(report: dict) -> dict[str, dict]:
        return {"": report.pop("unrefined"), "_rgb": report} if refine_rgb else {"": report}

    both = 0.1 if refine_rgb else None  # the held-out sets' estimates, all of them, before and after the refinement
    held = [pipelines(evaluate(model, where, "train_pbr", refine_rgb=refine_rgb, unrefined_min_score=both))
            for where in held_out]
    min_score = {how: max(score_threshold(h[how], HELD_OUT_FALSE_POSITIVES, HELD_OUT_KEEP_FOUND) for h in held)
                 for how in held[0]}
    final = "_rgb" if refine_rgb else ""
    real = pipelines(evaluate(model, root, split, max_images=max_images, min_score=min_score[final],
                              refine_rgb=refine_rgb, unrefined_min_score=min_score[""] if refine_rgb else None))
    figures_of = {}
    for how in held[0]:
        reports = (held[0][how], held[1][how], real[how])
        for report, where in zip(reports, out[how]):
            write_eval_report(report, where)
        figures_of[how] = tuple(figures(r) for r in reports)
    return figures_of


def describe(name: str, figures: dict) -> str:
    """One object's figures in words (with BOP's top-n rule's where the split names its targets)."""
    top = figures["top_n"]
    return (f"{name} {figures['metric']} 0.1d recall {figures['recall_0_1d']:.3f}, AUC {figures['auc']:.3f}, "
            f"{figures['false_positives_per_image']:.2f} false positives per image, {figures['misses']} of "
            f"{figures['instances']} missed (min score {figures['min_score']:.2f}; "
            f"{describe_found(figures['found_poses'])})"
            + (f"; top-n: recall {top['recall_0_1d']:.3f}, AUC {top['auc']:.3f}, {top['off_target_per_image']:.2f} "
               "off-target per image" if top else ""))


PER_IMAGE = {"false_positives_per_image": "false positives per image",  # the open world
             "off_target_per_image": "off-target estimates per image"}  # BOP's top-n rule


def summary_line(name: str, means: dict, objects: int, per_image: str = "false_positives_per_image") -> str:
    """The closing line of ``means`` (recall, AUC and the ``per_image`` count: a key of PER_IMAGE) over
    ``objects``."""
    return (f"{name}: mean ADD(-S) 0.1d recall {means['recall_0_1d']:.3f}, AUC {means['auc']:.3f}, "
            f"{PER_IMAGE[per_image]} {means[per_image]:.2f} over {objects} objects")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--real", required=True, help="BOP dataset root with real photos")
    parser.add_argument("--split", default="test")
    parser.add_argument("--objects", required=True, help="obj_ids, comma-separated")
    parser.add_argument("--frames", type=int, default=2400, help="training frames (all objects share them)")
    parser.add_argument("--epochs", type=int, default=20)
    parser.add_argument("--held-out-frames", type=int, default=HELD_OUT_FRAMES,
                        help="generated held-out frames, which set the detection score")
    parser.add_argument("--distance", type=float, nargs=2, default=(0.4, 1.4), help="camera distance range, m")
    parser.add_argument("--max-images", type=int, help="real images per scene to score (default: all)")
    parser.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    parser.add_argument("--out", required=True)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--variant", choices=("light", "pretrained"), default=VARIANT)
    parser.add_argument("--zoom-epochs", type=int, default=ZoomConfig.model_fields["epochs"].default,
                        help="the zoom network's epochs")
    parser.add_argument("--no-zoom", dest="zoom", action="store_false",
                        help="no offsets look: DOPE's poses as PnP and the distance head place them")
    parser.add_argument("--no-outline", dest="outline", action="store_false",
                        help="no outline look after the offsets look")
    parser.add_argument("--refine-rgb", action="store_true",
                        help="also refine the poses against the images and score those in the summary line")
    parser.add_argument("--generate", nargs="*", default=[], help="generate overrides (key=value) of the data")
    parser.add_argument("--train", nargs="*", default=[], help="TrainConfig fields (key=value) on the recipe's")
    parser.add_argument("--zoom-train", nargs="*", default=[],
                        help="ZoomConfig fields (key=value) of the zoom network, e.g. rotation=true view=colour")
    args = parser.parse_args()
    root, out = Path(args.real), Path(args.out)
    try:
        ids = [int(v) for v in args.objects.split(",")]
    except ValueError:
        raise PegasusError(f"--objects {args.objects!r}: comma-separated integer obj_ids expected") from None
    if (min(args.frames, args.held_out_frames) < FRAMES_PER_SCENE or min(args.epochs, args.zoom_epochs) < 1
            or not 0 < args.distance[0] < args.distance[1] < 20):
        raise PegasusError(f"--frames and --held-out-frames >= {FRAMES_PER_SCENE}, --epochs and --zoom-epochs >= 1 "
                           "and 0 < near < far <= 20 m expected")
    options, zoom_options = parse_options(args.train), parse_options(args.zoom_train)
    if taken := [k for k in zoom_options if k in ("data", "object", "out", "epochs", "device", "seed", "look")]:
        raise PegasusError(f"--zoom-train {taken[0]}: set by real.py itself (its data and runs, --zoom-epochs, "
                           "--device, --seed, the two looks)")
    zoom_fields = {"data": [str(out / "data")], "epochs": args.zoom_epochs,
                   "background_photos": options.get("background_photos"), "device": args.device, "seed": args.seed,
                   **zoom_options}
    # the outline look: the zoom's fields but its own look, without the offsets look's rotation and view
    outline_fields = {**{k: v for k, v in zoom_fields.items() if k not in ("rotation", "view")}, "look": "outline"}
    for fields in (zoom_fields, outline_fields):  # before anything is written
        config_from_args(ZoomConfig, argparse.Namespace(), object=str(ids[0]), **fields)
    camera = real_camera(root, args.split)
    models_info = read_json(root / "models" / "models_info.json")
    infos = object_infos(root, models_info, ids)
    times, t0 = {}, time.monotonic()

    demo, library = AssetLibrary(out / "demo_library"), AssetLibrary(out / "library")
    build_demo_library(demo)  # its environments only: its objects' obj_ids may be the real ones'
    for m in demo.manifests():
        if m.kind == "environment" and m.name not in library.names():
            shutil.copytree(demo.asset_path(m.name), library.asset_path(m.name))
    clutter = clutter_ids(root, models_info, ids, args.seed)
    for i in [*ids, *clutter]:
        if f"real_{i}" not in library.names():
            import_mesh(root / "models" / f"obj_{i:06d}.ply", f"real_{i}", "object", library, obj_id=i, scale=0.001)
    times["library"] = time.monotonic() - t0

    t0 = time.monotonic()
    diameters = {i: infos[i]["diameter"] / 1000.0 for i in ids}
    focal = {i: network_focal(diameters[i], args.distance, camera) for i in ids}
    cam = training_camera(float(np.median(list(focal.values()))), camera)
    objects = "[" + ", ".join([*(f"{{asset: real_{i}, count: [1, 1]}}" for i in ids),
                               *(f"{{asset: real_{i}, count: [0, 1]}}" for i in clutter)]) + "]"
    common = [f"library={library.root}", f"environments={ENVIRONMENTS}", f"objects={objects}",
              f"min_objects={len(ids)}", f"frames_per_scene={FRAMES_PER_SCENE}", *DISTRACTORS, f"packed={PACKED}",
              "appearance.retexture=0.5", f"appearance.shutter={SHUTTER}",
              f"appearance.object_hue_deg={OBJECT_HUE_DEG}", f"appearance.object_light={OBJECT_LIGHT}",
              f"appearance.object_specular={OBJECT_SPECULAR}",
              f"trajectory.distance=[{args.distance[0]}, {args.distance[1]}]",
              "trajectory.elevation_deg=[20, 75]", f"upright={UPRIGHT}", "antialiased=true",
              f"device={'cuda' if args.device == 'cuda' else 'cpu'}",
              *(f"camera.{k}={v}" for k, v in cam.items()), *args.generate]
    data = make_dataset(out / "data", [*common, f"scenes={args.frames // FRAMES_PER_SCENE}", f"seed={args.seed}"])
    held_out = make_dataset(out / "held_out",
                            [*common, f"scenes={args.held_out_frames // FRAMES_PER_SCENE}", f"seed={args.seed + 1000}"])
    backed = held_out_photos(out / "held_out_photos", held_out, options.get("background_photos"), args.seed)
    times["generate"] = time.monotonic() - t0

    hows = ("", "_rgb") if args.refine_rgb else ("",)  # DOPE and its zoom, and refined against the images
    rows = {}
    for i in ids:
        t0 = time.monotonic()
        run = out / "runs" / f"obj_{i:06d}"
        started = (run / "last.pt").is_file()
        if not started or load_checkpoint(run / "last.pt")["epoch"] < args.epochs:  # new, or cut short: resumed
            fields = {**train_fields(focal[i], args.epochs), "variant": args.variant, "seed": args.seed,
                      **options}  # --train seed=N: another training draw on the same data
            train(TrainConfig(data=[str(data)], object=str(i), out=str(run), device=args.device, **fields),
                  resume=started)
        times[f"train obj {i}"] = time.monotonic() - t0
        t0 = time.monotonic()
        looks = [(run / "zoom.pt", zoom_fields)] * args.zoom + [(run / "outline.pt", outline_fields)] * args.outline
        for zoom, fields in looks:
            trained_zoom(zoom, ZoomConfig(**fields, object=str(i), out=str(zoom)))
        times[f"zoom obj {i}"] = time.monotonic() - t0
        t0 = time.monotonic()
        model = DopeModel(run / "last.pt", device="cpu" if args.device == "cpu" else "auto",
                          zoom=[zoom for zoom, _ in looks] or None)
        rows[i] = {"focal_px": focal[i], "diameter_m": diameters[i]}
        where = {how: tuple(out / f"eval{kind}{how}" / f"obj_{i:06d}" for kind in ("_synthetic", "_photo_backed", ""))
                 for how in hows}
        for how, figs in scored(model, (held_out, backed), root, args.split, args.max_images, where,
                                args.refine_rgb).items():
            rows[i][f"synthetic{how}"], rows[i][f"photo_backed{how}"], rows[i][f"real{how}"] = figs
        times[f"evaluate obj {i}"] = time.monotonic() - t0
        shared = (times["library"] + times["generate"]) / len(ids)
        rows[i]["minutes"] = round((shared + sum(times[f"{step} obj {i}"] for step in ("train", "zoom", "evaluate")))
                                   / 60, 1)
        refined = [describe('refined', rows[i]['real_rgb'])] if args.refine_rgb else []
        synthetic = [f"synthetic held-out recall {rows[i][f'synthetic{how}']['recall_0_1d']:.3f}, AUC "
                     f"{rows[i][f'synthetic{how}']['auc']:.3f}{' refined' if how else ''}"
                     for how in hows]
        print(f"obj {i}: " + "; ".join([describe('real', rows[i]['real']), *refined, *synthetic,
                                        f"{rows[i]['minutes']:.1f} min"]), flush=True)

    means = {key: {k: float(np.mean([rows[i][key][k] for i in ids]))
                   for k in ("recall_0_1d", "auc", "false_positives_per_image")}
             for key in (f"real{how}" for how in hows)}
    final = "real_rgb" if args.refine_rgb else "real"  # the summary line's estimates
    if all(rows[i][final]["top_n"] for i in ids):
        means["top_n"] = {k: float(np.mean([rows[i][final]["top_n"][k] for i in ids]))
                          for k in ("recall_0_1d", "auc", "off_target_per_image")}
    doc = {"real": str(root), "split": args.split, "camera": {"K": camera.K.tolist(), "width": camera.width,
                                                             "height": camera.height},
           "training_camera": cam, "frames": args.frames, "held_out_frames": args.held_out_frames,
           "epochs": args.epochs, "zoom_epochs": args.zoom_epochs if args.zoom or args.outline else None,
           "outline": args.outline,
           "distance_m": list(args.distance),
           "variant": args.variant, "clutter": clutter, "generate": args.generate, "train": args.train,
           "zoom_train": args.zoom_train,
           "rgb_refined": args.refine_rgb, "objects": {str(i): rows[i] for i in ids}, "mean": means[final],
           "mean_unrefined": means["real"], "mean_top_n": means.get("top_n"), "seconds": times,
           "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}"}
    (out / "real.json").write_text(json.dumps(doc, indent=1))
    if args.refine_rgb:
        print(summary_line("real, without the RGB refinement", means["real"], len(ids)))
    if "top_n" in means:  # the split names its targets: the counts of instances a method is told under BOP's rule
        print(summary_line("real, BOP's top-n rule", means["top_n"], len(ids), "off_target_per_image"))
    print(summary_line("real", means[final], len(ids)))
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except PegasusError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)

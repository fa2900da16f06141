"""DOPE training recipes on a CPU, measured on a fixed held-out set: what ``docs/TRAINING.md`` reports.

Usage: python benchmarks/training.py --work out/bench-training [--tag NAME] [--recipe demo|dope] [--frames 960]
       [--per-scene 12] [--camera-fx 554] [--train key=value ...] [--generate key=value ...] [--reuse RUN]

Each run: the demo library; a training dataset of the demo's target object (noodle_cup_red, 1-2 per scene, 0-1 of
each distractor) on wooden_table and tiled_floor (``--frames`` frames, ``--per-scene`` per scene, at 320x240,
camera fx ``--camera-fx``, generate's defaults (shadows, appearance randomisation, 1-3 distractors) with the
``--generate key=value`` overrides on top, e.g. ``shadows.enabled=false appearance.enabled=false
distractors.count=[0,0]`` for the plain render; made once per setting and reused from ``--work``); the held-out
set, made once (store_shelf, left out of training, 2 scenes x 15 frames at 640x480 with the simulated cell's
camera: 60 degree field of view, 0.55-0.8 m, 45-65 degrees elevation); a training run with the recipe (``demo``:
the demo's, from ``nodes.demo_loop.DemoSettings``; ``dope``: TrainConfig's defaults, DOPE's) and the TrainConfig fields
given as ``--train key=value`` on top (values parsed as YAML); the held-out ADD-S AUC (0-10 cm) and pass rates of
DOPE alone and with depth refinement. Prints one row and appends it to ``--work``/results.csv. ``--reuse RUN``
skips the training and scores the finished run ``--work``/runs/RUN with today's decoder (the row's train figures
are then empty).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import platform
import time
from pathlib import Path

import torch

from dope_training.evaluate import evaluate, write_eval_report
from dope_training.infer import DopeModel
from dope_training.train import read_losses, train
from dope_training.train_config import TrainConfig, parse_options
from nodes.demo_loop import DemoSettings, held_out_overrides
from pegasus_gen.assets.demo_library import build_demo_library
from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.dataset.config import load_config
from pegasus_gen.dataset.generate import generate

TARGET = "noodle_cup_red"
OBJECTS = (f"[{{asset: {TARGET}, count: [1, 2]}}, {{asset: snack_box, count: [0, 1]}}, "
           "{asset: drink_can, count: [0, 1]}]")



def dataset(folder: Path, overrides: list[str]) -> Path:
    """The dataset of ``overrides`` in ``folder``, generated unless a finished one is there."""
    done = folder / "finished"
    if not done.is_file():
        generate(load_config(None, [f"output={folder}", "device=cpu", *overrides]), resume=folder.exists())
        done.write_text("\n".join(overrides))
    return folder


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", default="out/bench-training")
    parser.add_argument("--tag", default="run")
    parser.add_argument("--frames", type=int, default=960, help="training frames")
    parser.add_argument("--per-scene", type=int, default=12, help="training frames per scene")
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=240)
    parser.add_argument("--recipe", choices=("demo", "dope"), default="demo")
    parser.add_argument("--camera-fx", type=float, default=DemoSettings.small().camera_fx,
                        help="training camera fx, px (0: 60 degree fov)")
    parser.add_argument("--distance", default="[0.45, 0.85]", help="training camera distance range, m")
    parser.add_argument("--elevation", default="[30, 70]", help="training camera elevation range, degrees")
    parser.add_argument("--train", nargs="*", default=[], help="TrainConfig fields as key=value")
    parser.add_argument("--generate", nargs="*", default=[],
                        help="training-data generate overrides as key=value (e.g. shadows.enabled=true)")
    parser.add_argument("--reuse", help="score this finished run in --work/runs instead of training")
    args = parser.parse_args()
    work = Path(args.work)
    lib = AssetLibrary(None)
    build_demo_library(lib)
    camera = [f"camera.fx={args.camera_fx}", f"camera.fy={args.camera_fx}"] if args.camera_fx else []
    train_overrides = [f"library={lib.root}", "environments=[wooden_table, tiled_floor]", f"objects={OBJECTS}",
                       f"scenes={args.frames // args.per_scene}", f"frames_per_scene={args.per_scene}",
                       f"camera.width={args.width}", f"camera.height={args.height}", *camera,
                       f"trajectory.distance={args.distance}", f"trajectory.elevation_deg={args.elevation}",
                       *args.generate]
    resolved = load_config(None, train_overrides).model_dump(mode="json", exclude={"library"})
    name = f"train_{args.frames}_" + hashlib.sha256(json.dumps(resolved, sort_keys=True).encode()).hexdigest()[:10]
    reused = work / "runs" / args.reuse if args.reuse else None
    if reused is not None and not (reused / "last.pt").is_file():
        raise SystemExit(f"--reuse {args.reuse}: no {reused / 'last.pt'}")
    t0 = time.monotonic()
    # named by its whole config: no stale reuse; not needed to score a finished run
    data = None if reused else dataset(work / "datasets" / name, train_overrides)
    held_out = dataset(work / "datasets" / "held_out", held_out_overrides(lib.root, TARGET, frames=15))
    t_data = time.monotonic() - t0

    demo = DemoSettings.small()
    fields = demo.train_fields() if args.recipe == "demo" else {}
    fields |= parse_options(args.train)
    if reused:
        out, t_train, rate = reused, None, None
    else:
        out = work / "runs" / args.tag
        cfg = TrainConfig(data=[str(data)], object=TARGET, out=str(out), device="cpu", **fields)
        t0 = time.monotonic()
        train(cfg)
        t_train = time.monotonic() - t0
        rate = round(sum(r["images"] for r in read_losses(out / "loss.csv")) / t_train, 1)
    rows = read_losses(out / "loss.csv")
    report = evaluate(DopeModel(out / "last.pt"), held_out, "train_pbr", refine=True)
    write_eval_report(report, out / f"eval_held_out{'_' + args.tag if args.reuse else ''}")
    dope, refined = report["ADD-S"], report["refined"]["ADD-S"]
    row = {"tag": args.tag, "recipe": args.recipe, "frames": args.frames, "camera_fx": args.camera_fx,
           "generate": " ".join(args.generate), "train": " ".join(args.train),
           "train_min": None if t_train is None else round(t_train / 60, 1), "images_per_s": rate,
           "final_loss": round(rows[-1]["loss"], 5),
           "instances": report["instances"], "misses": report["misses"], "false_positives": report["false_positives"],
           "adds_auc": round(dope["auc_0_10cm"], 3), "pass_2cm": round(dope["pass_2cm"], 3),
           "pass_5cm": round(dope["pass_5cm"], 3), "refined_adds_auc": round(refined["auc_0_10cm"], 3),
           "refined_pass_2cm": round(refined["pass_2cm"], 3), "refined_pass_5cm": round(refined["pass_5cm"], 3),
           "rejected": report["refined"]["rejected"], "data_min": round(t_data / 60, 1),
           "per_scene": args.per_scene}
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}")
    print(row)
    results = work / "results.csv"
    new = not results.is_file()
    with open(results, "a", newline="") as f:
        writer = csv.DictWriter(f, list(row))
        if new:
            writer.writeheader()
        writer.writerow(row)


if __name__ == "__main__":
    main()

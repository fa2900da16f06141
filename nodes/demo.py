"""The built-in demo (``make demo``, ``pegasus demo-loop``): the generate-train-deploy loop on the demo
assets, an evaluation on frames of an environment left out of training, the closed-loop grasp evaluation
in the simulated cell, and an HTML report with the figures.

Small settings (default) fit a 2-core CPU in about 13 minutes; ``full`` gives the GPU-scale run (a
5,000-frame dataset at 640x480, the full DOPE network, 20 grasp attempts over two objects).
"""

from __future__ import annotations

import html
import json
import shutil
import time
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from nodes.launch import run as run_launch
from pegasus_gen.errors import PegasusError


class DemoSettings(BaseModel):
    """The sizes of a demo run: the dataset, the network and its training, the grasp evaluation."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    scenes: int = Field(gt=0, description="generated scenes")
    frames: int = Field(gt=0, description="frames per scene")
    width: int = Field(gt=0, description="image width, px")
    height: int = Field(gt=0, description="image height, px")
    variant: Literal["full", "light"] = Field(description="DOPE network variant")
    size: int = Field(gt=0, description="training crop size, px")
    epochs: int = Field(gt=0, description="training epochs")
    attempts: int = Field(gt=0, description="grasp attempts in the simulated cell")
    objects: str = Field(description="assets grasped (comma-separated); the first is the trained object")
    device: Literal["auto", "cpu", "cuda"] = Field(description="where generation, training and inference run")
    time_scale: float = Field(gt=0, description="simulated cell speed-up")
    environments: tuple[str, ...] = Field(("wooden_table", "tiled_floor"), min_length=1,
                                          description="environments of the training dataset")
    held_out_environment: str = Field("store_shelf", description="environment of the evaluation frames, "
                                                                 "left out of training")
    distractors: tuple[str, ...] = Field(("snack_box", "drink_can"), description="other objects in the training "
                                         "scenes (0 or 1 of each)")
    infer_images: int = Field(3, gt=0, description="dataset images the inference node estimates poses in")

    @classmethod
    def small(cls) -> "DemoSettings":
        """Fits a 2-core CPU in about 13 minutes (160 px crops: the light model leaves its all-zero start
        sooner on small crops)."""
        return cls(scenes=8, frames=12, width=320, height=240, variant="light", size=160, epochs=80, attempts=10,
                   objects="noodle_cup_red", device="cpu", time_scale=3.0)

    @classmethod
    def full(cls) -> "DemoSettings":
        """The GPU-scale run: 5,000 frames at 640x480, the full DOPE network, 20 grasp attempts."""
        return cls(scenes=200, frames=25, width=640, height=480, variant="full", size=400, epochs=30, attempts=20,
                   objects="noodle_cup_red", device="auto", time_scale=2.0)


def run_demo(out: str | Path, full: bool = False, library: str | None = None, host: str = "127.0.0.1") -> Path:
    """Run every step into ``out`` (refused when it is not empty) and return the report's path."""
    from pegasus_gen.assets.demo import build_demo_library
    from pegasus_gen.assets.library import AssetLibrary

    s = DemoSettings.full() if full else DemoSettings.small()
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise PegasusError(f"{out} is not empty: choose another --out or remove it")
    out.mkdir(parents=True, exist_ok=True)
    lib = AssetLibrary(library)
    build_demo_library(lib)
    lib_args = [f"library={lib.root}"]
    times = {}

    t0 = time.monotonic()
    dataset, train_run = out / "dataset", out / "train"
    target = s.objects.split(",")[0]
    objects = "[" + ", ".join([f"{{asset: {target}, count: [1, 2]}}"]
                              + [f"{{asset: {d}, count: [0, 1]}}" for d in s.distractors]) + "]"
    nodes = run_launch("generate_train_deploy.launch.py", [
        f"object:={target}", f"output:={dataset}", f"run:={train_run}", f"scenes:={s.scenes}",
        f"frames:={s.frames}", f"width:={s.width}", f"height:={s.height}", f"epochs:={s.epochs}",
        f"variant:={s.variant}", f"size:={s.size}", f"device:={s.device}",
        f"images:={dataset / 'train_pbr' / '000000' / 'rgb'}",
        f"max_images:={s.infer_images}", f"library:={lib.root}", f"environments:=[{', '.join(s.environments)}]",
        f"objects_config:={objects}"])
    times["generate, train, export, infer (launch)"] = time.monotonic() - t0
    model = train_run / "model.onnx"
    if not model.is_file():
        raise PegasusError(f"the generate-train-deploy loop ended without a model ({[n.get_name() for n in nodes]})")

    t0 = time.monotonic()
    from dope_training.evaluate import evaluate, write_report
    from dope_training.infer import DopeModel
    from pegasus_gen.dataset.config import load_config
    from pegasus_gen.dataset.generate import generate

    held_out = generate(load_config(None, [f"output={out / 'held_out'}", *lib_args, "scenes=1",
                                           f"frames_per_scene={max(s.frames, 10)}", f"camera.width={s.width}",
                                           f"camera.height={s.height}", f"device={s.device}",
                                           f"environments=[{s.held_out_environment}]", "seed=1000",
                                           f"objects=[{{asset: {target}, count: [1, 2]}}]"]))
    report = evaluate(DopeModel(model), held_out, "train_pbr")
    eval_json, eval_png = write_report(report, out / "eval_held_out")
    times["evaluate on a held-out environment"] = time.monotonic() - t0

    t0 = time.monotonic()
    run_launch("sim_pick_place.launch.py", [
        f"model:={model}", f"attempts:={s.attempts}", f"objects:={s.objects}", f"library:={lib.root}",
        f"host:={host}", f"time_scale:={s.time_scale}", f"report:={out / 'sim_grasp'}", f"device:={s.device}"])
    times["closed-loop grasping (simulated cell)"] = time.monotonic() - t0
    grasp = json.loads((out / "sim_grasp" / "report.json").read_text())
    return write_html(out, s, report, grasp, times, train_run)


def write_html(out: Path, s: DemoSettings, evaluation: dict, grasp: dict, times: dict, train_run: Path) -> Path:
    """``out``/report.html: settings, timings, the loss curve, a belief snapshot, the ADD curve and the
    grasp strip."""
    figures = out / "figures"
    figures.mkdir(exist_ok=True)
    snapshots = sorted((train_run / "beliefs").glob("*.png"))
    for src, name in ((train_run / "loss.png", "loss.png"), (snapshots[-1] if snapshots else None, "beliefs.png"),
                      (out / "eval_held_out" / "eval_curve.png", "eval_curve.png"),
                      (out / "sim_grasp" / "strip.png", "grasp_strip.png")):
        if src is not None and src.is_file():
            shutil.copy(src, figures / name)
    r = evaluation["result"]
    rows = "".join(f"<tr><td>{html.escape(k)}</td><td>{v:.0f} s</td></tr>" for k, v in times.items())
    causes = ", ".join(f"{k}: {v}" for k, v in grasp["failure_causes"].items()) or "none"
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>PEGASUS demo</title>
<style>body{{font-family:sans-serif;max-width:1000px;margin:auto}} img{{max-width:100%}} td{{padding:2px 10px}}</style>
</head><body><h1>PEGASUS demo: generate, train, deploy, grasp</h1>
<p>Settings: {s.scenes} scenes x {s.frames} frames at {s.width}x{s.height}; DOPE-{s.variant} on {s.size} px crops,
{s.epochs} epochs on {s.device}; {s.attempts} grasp attempts ({html.escape(s.objects)}).</p>
<table>{rows}</table>
<h2>Training</h2><img src="figures/loss.png"><img src="figures/beliefs.png">
<h2>Pose accuracy on an environment left out of training</h2>
<p>{evaluation['object']['name']}: {evaluation['instances']} instances, {evaluation['misses']} missed;
{evaluation['metric']} AUC (0-10 cm) {r['auc_0_10cm']:.3f}; pass rate at 2 / 5 / 10 cm
{r['pass_2cm']:.2f} / {r['pass_5cm']:.2f} / {r['pass_10cm']:.2f}.</p><img src="figures/eval_curve.png">
<h2>Closed-loop grasping in the simulated cell</h2>
<p>{grasp['successes']} of {grasp['attempts']} objects in the basket ({grasp['pose_source']} poses); failure causes:
{html.escape(causes)}; median ADD-S of the estimates
{'-' if grasp['median_adds_m'] is None else f"{grasp['median_adds_m'] * 100:.1f} cm"}.</p>
<img src="figures/grasp_strip.png">
</body></html>"""
    path = out / "report.html"
    path.write_text(page)
    return path

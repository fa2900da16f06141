"""The built-in demo (``make demo``, ``pegasus demo-loop``): the generate-train-deploy loop on the demo
assets, an evaluation on frames of an environment left out of training, the closed-loop grasp evaluation
in the simulated cell, and an HTML report with the figures.

Small settings (default) fit a 2-core CPU in about 20 minutes; ``full`` gives the GPU-scale run (a
5,000-frame dataset at 640x480, the full DOPE network, 20 grasp attempts over two objects).
"""

from __future__ import annotations

import html
import json
import shutil
import time
from pathlib import Path
from typing import Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field

from dope_training.train_config import parse_options
from nodes.launch import run as run_launch
from pegasus_gen.errors import PegasusError
from robot_bridge.cell import SIM_CELL

# The simulated cell's camera (robot_bridge.cell): its image size and field of view (fx rounded to a pixel for the
# training images), 0.55-0.8 m from the pick area, looking down at 45-65 degrees.
CELL_CAMERA_FX = float(round(SIM_CELL.camera_fx))
HELD_OUT_CAMERA = [f"camera.width={SIM_CELL.camera_size[0]}", f"camera.height={SIM_CELL.camera_size[1]}",
                   f"camera.fov_deg={SIM_CELL.camera_fov_deg:g}", "trajectory.distance=[0.55, 0.8]",
                   "trajectory.elevation_deg=[45, 65]"]


PLAIN_RENDER = ["shadows.enabled=false", "appearance.enabled=false", "distractors.count=[0, 0]"]


class DemoSettings(BaseModel):
    """The sizes of a demo run: the dataset, the network and its training, the grasp evaluation."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    scenes: int = Field(gt=0, description="generated scenes")
    frames: int = Field(gt=0, description="frames per scene")
    width: int = Field(gt=0, description="image width, px")
    height: int = Field(gt=0, description="image height, px")
    camera_fx: float = Field(CELL_CAMERA_FX, gt=0, description="training camera focal length, px (the cell "
                             "camera's, so objects appear at the size the robot's camera sees them)")
    distance: tuple[float, float] = Field((0.45, 0.85), description="training camera distance range, m")
    elevation_deg: tuple[float, float] = Field((30.0, 70.0), description="training camera elevation range")
    variant: Literal["full", "light", "pretrained"] = Field(description="DOPE network variant")
    distance_head: bool = Field(False, description="the network also learns each object's distance from how large "
                                                   "it looks (pegasus train --distance-head)")
    size: int = Field(gt=0, description="training crop size, px")
    focal_px: float = Field(330.0, ge=0, description="network-input focal length, px")
    lr: float = Field(0.002, gt=0, description="Adam learning rate")
    schedule: Literal["constant", "cosine"] = Field("cosine", description="learning rate schedule")
    peak_weight: float = Field(10.0, ge=0, description="belief cells' error weight 1 + this * target")
    symmetry_axis: tuple[float, float, float] | None = Field(
        (0.0, 0.0, 1.0), description="the trained object's shape symmetry axis (canonical labels; None: none)")
    epochs: int = Field(gt=0, description="training epochs")
    attempts: int = Field(gt=0, description="grasp attempts in the simulated cell")
    objects: str = Field(description="assets grasped (comma-separated); the first is the trained object")
    device: Literal["auto", "cpu", "cuda"] = Field(description="where generation, training and inference run")
    time_scale: float = Field(gt=0, description="simulated cell speed-up")
    environments: tuple[str, ...] = Field(("wooden_table", "tiled_floor"), min_length=1,
                                          description="environments of the training dataset")
    held_out_environment: str = Field("store_shelf", description="environment of the evaluation frames, "
                                                                 "left out of training")
    # the scenes, more than the frames, set the spread of the held-out figures: two networks that score alike on
    # 24 scenes (ADD-S AUC 0.58 and 0.59 over 617 cups) scored 0.54 and 0.69 on 2 scenes of 10 frames
    held_out_scenes: int = Field(8, gt=0, description="scenes of the held-out set")
    held_out_frames: int = Field(6, gt=0, description="frames per held-out scene")
    distractors: tuple[str, ...] = Field(("snack_box", "drink_can"), description="other objects in the training "
                                         "scenes (0 or 1 of each)")
    shadow_share: float = Field(0.5, ge=0, le=1, description="share of the training scenes with contact shadows "
                                "(a network that always sees them reads the plain held-out cups 5-6 % too near)")
    infer_images: int = Field(3, gt=0, description="dataset images the inference node estimates poses in")

    @classmethod
    def small(cls) -> "DemoSettings":
        """Fits a 2-core CPU in about 20 minutes."""
        return cls(scenes=80, frames=12, width=320, height=240, variant="pretrained", distance_head=True, size=128,
                   epochs=28, attempts=10, objects="noodle_cup_red", device="cpu", time_scale=3.0)

    @classmethod
    def full(cls) -> "DemoSettings":
        """The GPU-scale run: 5,000 frames at 640x480, the full DOPE network, 20 grasp attempts."""
        return cls(scenes=200, frames=25, width=640, height=480, variant="full", size=400, epochs=30, attempts=20,
                   objects="noodle_cup_red", device="auto", time_scale=2.0)

    def train_options(self) -> str:
        """The recipe's TrainConfig fields beyond the launch file's own arguments, as trainer_node's options."""
        axis = "null" if self.symmetry_axis is None else "[" + ",".join(f"{v:g}" for v in self.symmetry_axis) + "]"
        return (f"focal_px={self.focal_px:g} lr={self.lr:g} schedule={self.schedule} "
                f"peak_weight={self.peak_weight:g} symmetry_axis={axis} "
                f"distance_head={'true' if self.distance_head else 'false'}")

    def train_fields(self) -> dict:
        """The recipe as TrainConfig fields (variant, crop size, epochs and ``train_options``), for a training run
        outside the launch file."""
        return {"variant": self.variant, "size": self.size, "epochs": self.epochs,
                **parse_options(self.train_options())}

    def dataset_config(self, library: str | Path) -> dict:
        """The training dataset's generation config (``pegasus generate`` YAML keys)."""
        target = self.objects.split(",")[0]
        return {"library": str(library), "environments": list(self.environments),
                "objects": [{"asset": target, "count": [1, 2]}] + [{"asset": d, "count": [0, 1]}
                                                                   for d in self.distractors],
                "scenes": self.scenes, "frames_per_scene": self.frames, "device": self.device,
                "camera": {"width": self.width, "height": self.height, "fx": self.camera_fx, "fy": self.camera_fx},
                "trajectory": {"distance": list(self.distance), "elevation_deg": list(self.elevation_deg)},
                "shadows": {"share": self.shadow_share}}


def held_out_overrides(library: str | Path, target: str, environment: str = "store_shelf", scenes: int = 2,
                       frames: int = 10, device: str = "cpu") -> list[str]:
    """``pegasus generate`` overrides of a held-out set: ``target`` (1-2 per scene) in ``environment`` seen
    with the cell camera's intrinsics, distances and angles (``HELD_OUT_CAMERA``), seed 1000, rendered plain (no
    shadows, randomisation or distractors: the set every recipe in docs/TRAINING.md was scored on)."""
    return [f"library={library}", f"environments=[{environment}]", f"scenes={scenes}", f"frames_per_scene={frames}",
            f"device={device}", "seed=1000", f"objects=[{{asset: {target}, count: [1, 2]}}]", *HELD_OUT_CAMERA,
            *PLAIN_RENDER]


def stage_times(t0: float, dataset: Path, train_run: Path, t_end: float) -> dict[str, float]:
    """Seconds of each stage of the generate-train-deploy launch, from when its outputs were written
    (wall clock ``t0`` and ``t_end``: the launch's start and end): generate (until training wrote its
    config), train (until the last checkpoint), export (until model.onnx), infer (the rest)."""
    marks = [t0] + [(p.stat().st_mtime if p.is_file() else t_end)
                    for p in (train_run / "train_config.yaml", train_run / "last.pt", train_run / "model.onnx")]
    marks.append(t_end)
    names = ("generate (dataset)", "train", "export (ONNX)", "infer (inference node)")
    return {name: max(b - a, 0.0) for name, a, b in zip(names, marks, marks[1:])}


def run_demo(out: str | Path, settings: DemoSettings | None = None, library: str | None = None,
             host: str = "127.0.0.1") -> Path:
    """Run every step with ``settings`` (default: ``DemoSettings.small()``) into ``out`` (refused when it is
    not empty) and return the report's path; ``out``/summary.json holds its figures."""
    from pegasus_gen.assets.demo_library import build_demo_library
    from pegasus_gen.assets.library import AssetLibrary

    s = settings or DemoSettings.small()
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise PegasusError(f"{out} is not empty: choose another --out or remove it")
    out.mkdir(parents=True, exist_ok=True)
    lib = AssetLibrary(library)
    build_demo_library(lib)
    times = {}

    dataset, train_run = out / "dataset", out / "train"
    target = s.objects.split(",")[0]
    config = out / "dataset_config.yaml"
    config.write_text(yaml.safe_dump(s.dataset_config(lib.root), sort_keys=False))
    t0 = time.time()
    nodes = run_launch("generate_train_deploy.launch.py", [
        f"config:={config}", f"object:={target}", f"output:={dataset}", f"run:={train_run}", f"scenes:={s.scenes}",
        f"frames:={s.frames}", f"width:={s.width}", f"height:={s.height}", f"epochs:={s.epochs}",
        f"variant:={s.variant}", f"size:={s.size}", f"train_options:={s.train_options()}",
        f"device:={s.device}",
        f"images:={dataset / 'train_pbr' / '000000' / 'rgb'}", f"max_images:={s.infer_images}",
        f"library:={lib.root}"])
    times.update(stage_times(t0, dataset, train_run, time.time()))
    model = train_run / "model.onnx"
    if not model.is_file():
        raise PegasusError(f"the generate-train-deploy loop ended without a model ({[n.get_name() for n in nodes]})")

    t0 = time.monotonic()
    from dope_training.evaluate import evaluate, write_eval_report
    from dope_training.infer import DopeModel
    from pegasus_gen.dataset.config import load_config
    from pegasus_gen.dataset.generate import generate

    held_out = generate(load_config(None, [f"output={out / 'held_out'}", *held_out_overrides(
        lib.root, target, s.held_out_environment, s.held_out_scenes, s.held_out_frames, s.device)]))
    report = evaluate(DopeModel(model), held_out, "train_pbr", refine=True)
    write_eval_report(report, out / "eval_held_out")
    times["evaluate on a held-out environment"] = time.monotonic() - t0

    t0 = time.monotonic()
    run_launch("sim_pick_place.launch.py", [
        f"model:={model}", f"attempts:={s.attempts}", f"objects:={s.objects}", f"library:={lib.root}",
        f"host:={host}", f"time_scale:={s.time_scale}", f"report:={out / 'sim_grasp'}", f"device:={s.device}",
        "use_pose:=refined"])
    times["closed-loop grasping (simulated cell)"] = time.monotonic() - t0
    grasp = json.loads((out / "sim_grasp" / "report.json").read_text())
    summary = {"settings": s.model_dump(mode="json"), "stage_seconds": times,
               "held_out": {"instances": report["instances"], "metric": "ADD-S",
                            "dope": report["ADD-S"], "dope_depth": report["refined"]["ADD-S"],
                            "rejected_by_refinement": report["refined"]["rejected"]},
               "grasps": {k: grasp[k] for k in ("attempts", "successes", "failure_causes", "median_adds_m")}}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    return write_html(out, s, report, grasp, times, train_run)


def _accuracy_row(name: str, r: dict) -> str:
    median = "-" if r["median_m"] is None else f"{100 * r['median_m']:.1f}"
    return (f"<tr><td>{name}</td><td>{r['auc_0_10cm']:.3f}</td><td>{r['pass_2cm']:.2f}</td>"
            f"<td>{r['pass_5cm']:.2f}</td><td>{r['pass_10cm']:.2f}</td><td>{median}</td></tr>")


def write_html(out: Path, s: DemoSettings, evaluation: dict, grasp: dict, times: dict, train_run: Path) -> Path:
    """``out``/report.html: settings, the time of each stage, the loss curve, a belief snapshot, held-out
    accuracy of DOPE alone and with depth refinement, the ADD curves and the grasp results and strip."""
    figures = out / "figures"
    figures.mkdir(exist_ok=True)
    snapshots = sorted((train_run / "beliefs").glob("*.png"))
    for src, name in ((train_run / "loss.png", "loss.png"), (snapshots[-1] if snapshots else None, "beliefs.png"),
                      (out / "eval_held_out" / "eval_curve.png", "eval_curve.png"),
                      (out / "sim_grasp" / "strip.png", "grasp_strip.png")):
        if src is not None and src.is_file():
            shutil.copy(src, figures / name)
    rows = "".join(f"<tr><td>{html.escape(k)}</td><td>{v:.0f} s</td></tr>" for k, v in times.items())
    rows += f"<tr><td><b>total</b></td><td><b>{sum(times.values()) / 60:.1f} min</b></td></tr>"
    accuracy = "".join(_accuracy_row(name, r) for name, r in (
        ("DOPE", evaluation["ADD-S"]), ("DOPE + depth refinement", evaluation["refined"]["ADD-S"])))
    causes = ", ".join(f"{k}: {v}" for k, v in grasp["failure_causes"].items()) or "none"
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>PEGASUS demo</title>
<style>body{{font-family:sans-serif;max-width:1000px;margin:auto}} img{{max-width:100%}} td{{padding:2px 10px}}</style>
</head><body><h1>PEGASUS demo: generate, train, deploy, grasp</h1>
<p>Settings: {s.scenes} scenes x {s.frames} frames at {s.width}x{s.height} (fx {s.camera_fx:g} px);
DOPE-{s.variant}{" with a distance head" * s.distance_head} on {s.size} px crops
at {s.focal_px:g} px focal length, {s.epochs} epochs on {s.device};
{s.attempts} grasp attempts ({html.escape(s.objects)}) on depth-refined poses.</p>
<table>{rows}</table>
<h2>Training</h2><img src="figures/loss.png"><img src="figures/beliefs.png">
<h2>Pose accuracy on an environment left out of training</h2>
<p>{evaluation['object']['name']} in {html.escape(s.held_out_environment)}, seen with the cell camera:
{evaluation['instances']} instances, {evaluation['misses']} missed by DOPE, {evaluation['refined']['rejected']}
estimates rejected by the depth refinement (a rejected estimate counts as a miss).</p>
<table><tr><th></th><th>ADD-S AUC (0-10 cm)</th><th>pass 2 cm</th><th>pass 5 cm</th>
<th>pass 10 cm</th><th>median (cm)</th></tr>{accuracy}</table><img src="figures/eval_curve.png">
<h2>Closed-loop grasping in the simulated cell</h2>
<p>{grasp['successes']} of {grasp['attempts']} objects in the basket ({grasp['pose_source']} poses); failure causes:
{html.escape(causes)}; median ADD-S of the estimates
{'-' if grasp['median_adds_m'] is None else f"{grasp['median_adds_m'] * 100:.1f} cm"}.</p>
<img src="figures/grasp_strip.png">
</body></html>"""
    path = out / "report.html"
    path.write_text(page)
    return path

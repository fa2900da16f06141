"""The demo's settings and report: its dataset config is a valid generation config matched to the cell
camera, stage times come from the run's own files, and every figure in the report is the one it was given."""

import os
import time

import numpy as np
import pytest
import yaml

from nodes.demo_loop import CELL_CAMERA_FX, DemoSettings, held_out_overrides, stage_times, write_html
from pegasus_gen.dataset.config import load_config
from pegasus_gen.geometry.cameras import intrinsics_from_fov


def test_demo_datasets_see_objects_at_the_cell_cameras_scale(tmp_path):
    s = DemoSettings.small()
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(s.dataset_config(tmp_path / "lib")))
    cfg = load_config(path)
    cell_fx = intrinsics_from_fov(640, 480, 60.0)[0, 0]
    assert cfg.camera.fx == cfg.camera.fy == s.camera_fx == pytest.approx(cell_fx, rel=1e-3) == CELL_CAMERA_FX
    assert cfg.scenes * cfg.frames_per_scene == s.scenes * s.frames
    assert [o.asset for o in cfg.objects] == [s.objects.split(",")[0], *s.distractors]
    held_out = load_config(None, held_out_overrides(tmp_path / "lib", "noodle_cup_red"))
    assert held_out.environments == ["store_shelf"] and held_out.environments[0] not in s.environments
    assert (held_out.camera.width, held_out.camera.height, held_out.camera.fov_deg) == (640, 480, 60.0)


def test_stage_times_come_from_when_each_stage_wrote_its_output(tmp_path):
    t0 = time.time() - 100
    for name, at in (("train_config.yaml", 30), ("last.pt", 80), ("model.onnx", 85)):
        (tmp_path / name).write_text("x")
        os.utime(tmp_path / name, (t0 + at, t0 + at))
    times = stage_times(t0, tmp_path / "dataset", tmp_path, t0 + 97)
    assert list(times.values()) == pytest.approx([30, 50, 5, 12])
    assert sum(times.values()) == pytest.approx(97)


def test_report_shows_the_figures_it_was_given(tmp_path):
    rng = np.random.default_rng(3)

    def result():
        return {"auc_0_10cm": rng.uniform(), "pass_2cm": rng.uniform(), "pass_5cm": rng.uniform(),
                "pass_10cm": rng.uniform(), "median_m": rng.uniform(0.001, 0.1)}

    evaluation = {"object": {"name": "noodle_cup_red"}, "instances": 17, "misses": 3, "metric": "ADD-S",
                  "ADD-S": result(), "refined": {"rejected": 4, "ADD-S": result()}}
    grasp = {"attempts": 10, "successes": 7, "pose_source": "dope", "median_adds_m": 0.0123,
             "failure_causes": {"implausible estimate": 2, "missed grasp": 1}}
    times = {"generate (dataset)": 61.0, "train": 302.0, "closed-loop grasping (simulated cell)": 95.0}
    page = write_html(tmp_path, DemoSettings.small(), evaluation, grasp, times, tmp_path / "train").read_text()
    for r in (evaluation["ADD-S"], evaluation["refined"]["ADD-S"]):
        for key in ("auc_0_10cm",):
            assert f"{r[key]:.3f}" in page
        for key in ("pass_2cm", "pass_5cm", "pass_10cm"):
            assert f"{r[key]:.2f}" in page
        assert f"{100 * r['median_m']:.1f}" in page
    assert "7 of 10" in page and "implausible estimate: 2" in page and "1.2 cm" in page
    assert "17 instances, 3 missed" in page and "4\nestimates rejected" in page
    assert "302 s" in page and f"{458 / 60:.1f} min" in page


def test_the_demo_recipe_reaches_a_training_config_whole():
    from dope_training.train_config import TrainConfig

    s = DemoSettings.small()
    cfg = TrainConfig(data=["d"], object="noodle_cup_red", **s.train_fields())
    assert (cfg.variant, cfg.size, cfg.epochs, cfg.distance_head) == (s.variant, s.size, s.epochs, s.distance_head)
    assert (cfg.focal_px, cfg.lr, cfg.schedule, cfg.peak_weight) == (s.focal_px, s.lr, s.schedule, s.peak_weight)
    assert tuple(cfg.symmetry_axis) == s.symmetry_axis

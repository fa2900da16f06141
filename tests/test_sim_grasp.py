"""The closed loop in simulation: sim_pick_place.launch.py through `pegasus sim-grasp`: a simulated cell,
splat-rendered camera images, robot node through ur-rtde, evaluator with report and strip."""

import json
import os

import cv2

from pegasus_gen.assets.demo import build_demo_library
from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.cli.main import main


def test_sim_grasp_with_true_poses_puts_every_cup_in_the_basket(tmp_path, capsys):
    lib = AssetLibrary(tmp_path / "lib")
    build_demo_library(lib)
    host = f"127.0.{os.getpid() % 200 + 20}.202"
    assert main(["sim-grasp", "--ground-truth", "--attempts", "3", "--objects", "noodle_cup_red,noodle_cup_curry",
                 "--library", str(lib.root), "--host", host, "--time-scale", "3", "--device", "cpu",
                 "--out", str(tmp_path / "report")]) == 0
    report = json.loads((tmp_path / "report" / "report.json").read_text())
    assert report["attempts"] == 3 and report["successes"] == 3 and report["pose_source"] == "ground_truth"
    assert [r["object"] for r in report["records"]] == ["noodle_cup_red", "noodle_cup_curry", "noodle_cup_red"]
    assert all(r["adds_m"] < 1e-6 for r in report["records"])
    assert cv2.imread(str(tmp_path / "report" / "strip.png")).shape[1] == 5 * 320
    assert "3 of 3 in the basket" in capsys.readouterr().out


def test_sim_grasp_without_a_model_is_a_clear_error(capsys):
    assert main(["sim-grasp"]) == 2
    assert "--model" in capsys.readouterr().err

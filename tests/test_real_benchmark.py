"""The sim-to-real recipe's choices from the object's size and the camera, and benchmarks/real.py end to end on
a tiny generated stand-in for a real BOP test split."""

import importlib.util
import json
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import yaml

from dope_training.checkpoint import load_checkpoint
from dope_training.evaluate import score_threshold
from dope_training.keypoints import surface_keypoints
from dope_training.recipe import (
    HELD_OUT_FALSE_POSITIVES,
    HELD_OUT_KEEP_FOUND,
    KEYPOINTS,
    MAX_ENLARGE,
    OBJECT_PX,
    RealCamera,
    network_focal,
    training_camera,
)
from pegasus_gen.dataset.config import AppearanceConfig, load_config
from pegasus_gen.dataset.generate import generate
from pegasus_gen.formats.bop import model_boxes, read_model

ROOT = Path(__file__).resolve().parents[1]
KINECT = RealCamera(np.array([[572.41, 0, 325.26], [0, 573.57, 242.04], [0, 0, 1]]), 640, 480)


def test_the_network_sees_every_object_at_one_size_and_real_images_are_enlarged_at_most_max_enlarge():
    for diameter in (0.05, 0.1, 0.15, 0.3):
        focal = network_focal(diameter, (0.4, 1.4), KINECT)
        assert focal == pytest.approx(min(OBJECT_PX * 0.9 / diameter, MAX_ENLARGE * 572.41))
        # the object's diameter at 0.9 m, in network pixels
        assert focal * diameter / 0.9 == pytest.approx(OBJECT_PX) or focal == pytest.approx(MAX_ENLARGE * 572.41)
    assert network_focal(0.02, (0.4, 1.4), KINECT) == pytest.approx(MAX_ENLARGE * 572.41)  # a tiny object


def test_the_training_camera_is_the_real_one_scaled_to_the_network_focal_length():
    rng = np.random.default_rng(0)
    assert training_camera(900.0, KINECT) == training_camera(572.41, KINECT)  # never sharper than the camera
    for focal in (250.0, 353.0, 572.41):
        cam = training_camera(focal, KINECT)
        assert cam["width"] % 8 == 0 and cam["height"] % 8 == 0
        assert cam["fx"] == pytest.approx(focal, rel=0.02) and cam["width"] / cam["height"] == pytest.approx(4 / 3,
                                                                                                            rel=0.02)
        K = np.array([[cam["fx"], 0, cam["cx"]], [0, cam["fy"], cam["cy"]], [0, 0, 1]])
        points = rng.uniform([-0.3, -0.2, 0.5], [0.3, 0.2, 1.5], (50, 3))
        real = (points @ KINECT.K.T)[:, :2] / points[:, 2:]
        scaled = (points @ K.T)[:, :2] / points[:, 2:]
        s = np.array([cam["width"] / 640, cam["height"] / 480])
        np.testing.assert_allclose(scaled, (real + 0.5) * s - 0.5, atol=1e-2)  # the same image, resampled


@pytest.mark.slow
def test_benchmark_runs_from_a_bop_test_split_to_its_summary_line(library, tmp_path):
    real = tmp_path / "real"
    generate(load_config(None, [f"output={real}", f"library={library.root}", "split=test", "scenes=1",
                                "frames_per_scene=3", "camera.width=320", "camera.height=240", "device=cpu",
                                "environments=[tiled_floor]", "min_objects=2",
                                "objects=[{asset: 1, count: [1, 1]}, {asset: 2, count: [1, 1]}]"]))
    out = tmp_path / "bench"
    script = str(ROOT / "benchmarks" / "real.py")
    result = subprocess.run([sys.executable, script, "--real", str(real), "--objects", "1", "--frames", "16",
                             "--held-out-frames", "8", "--epochs", "1", "--zoom-epochs", "1", "--device", "cpu",
                             "--refine-rgb", "--out", str(out)],
                            capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr[-2000:]
    unrefined_line, top_line, last = result.stdout.strip().splitlines()[-3:]
    line = r"mean ADD\(-S\) 0\.1d recall \d\.\d{3}, AUC \d\.\d{3}, false positives per image \d+\.\d{2} over 1 objects"
    assert re.fullmatch(r"real, without the RGB refinement: " + line, unrefined_line), unrefined_line
    assert re.fullmatch(r"real: " + line, last), last
    assert re.fullmatch(r"real, BOP's top-n rule: mean ADD\(-S\) 0\.1d recall \d\.\d{3}, AUC \d\.\d{3}, "
                        r"off-target estimates per image \d+\.\d{2} over 1 objects", top_line), top_line
    doc = json.loads((out / "real.json").read_text())
    figures = doc["objects"]["1"]["real"]
    assert figures["images"] == 3 and figures["instances"] == 3  # every test image scored, one cup in each
    # BOP's rule: the split's targets say how many cups each image holds; the best-scoring estimates alone count
    targets = json.loads((real / "test_targets_bop19.json").read_text())
    refined = doc["objects"]["1"]["real_rgb"]  # the summary line's: the same photos, poses refined against them
    assert refined["images"] == 3 and refined["instances"] == 3 and doc["rgb_refined"]
    assert doc["mean"]["auc"] == refined["auc"] and doc["mean_unrefined"]["auc"] == figures["auc"]
    top = refined["top_n"]
    assert top["instances"] == sum(t["inst_count"] for t in targets if t["obj_id"] == 1) == 3
    assert top["recall_0_1d"] <= refined["recall_0_1d"] and doc["mean_top_n"]["auc"] == top["auc"]
    seconds = doc["seconds"]  # its minutes: its share of the library and data (one object here), training, scoring
    assert doc["objects"]["1"]["minutes"] == round(sum(seconds[k] for k in ("library", "generate", "train obj 1",
                                                                             "zoom obj 1", "evaluate obj 1")) / 60, 1)
    # the zoom network of the cup, trained on the same data, and the poses scored through it
    zoom = torch.load(out / "runs" / "obj_000001" / "zoom.pt", weights_only=True)
    assert zoom["obj_id"] == 1 and zoom["config"]["data"] == [str(out / "data")] and doc["zoom_epochs"] == 1
    assert json.loads((out / "runs" / "obj_000001" / "zoom.txt").read_text())["epochs"] == 1  # its fields recorded
    # then the outline look, of the same data and epochs
    outline = torch.load(out / "runs" / "obj_000001" / "outline.pt", weights_only=True)
    assert outline["look"] == "outline" and outline["config"]["data"] == [str(out / "data")] and doc["outline"]
    assert json.loads((out / "runs" / "obj_000001" / "outline.txt").read_text())["epochs"] == 1
    # the detection score holds the rule on the held-out frames as rendered and with unseen photos behind them
    held_out = [json.loads((out / f"eval_{kind}" / "obj_000001" / "eval.json").read_text())
                for kind in ("synthetic", "photo_backed")]
    assert held_out[1]["images"] == 8 and doc["objects"]["1"]["photo_backed"]["images"] == 8
    assert figures["min_score"] == pytest.approx(max(score_threshold(r, HELD_OUT_FALSE_POSITIVES, HELD_OUT_KEEP_FOUND)
                                                     for r in held_out))
    # the real set's other model is clutter in the training data (each scene holds it with probability 1/2: seeded)
    seen = {g["obj_id"] for p in (out / "data" / "train_pbr").glob("*/scene_gt.json")
            for gts in json.loads(p.read_text()).values() for g in gts}
    assert doc["clutter"] == [2] and seen == {1, 2}
    # each object's own hue turn: real.py's, wider than generate's default
    spec = importlib.util.spec_from_file_location("real_benchmark", script)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    hue = yaml.safe_load((out / "data" / "pegasus_config.yaml").read_text())["appearance"]["object_hue_deg"]
    assert hue == bench.OBJECT_HUE_DEG > AppearanceConfig().object_hue_deg
    # the network learns the recipe's points on the cup's surface, and inference reads them from its checkpoint
    state = load_checkpoint(out / "runs" / "obj_000001" / "last.pt")
    assert state["train_config"]["keypoints"] == KEYPOINTS == "surface"
    np.testing.assert_allclose(state["object"]["keypoints"],
                               surface_keypoints(read_model(out / "data", 1), *model_boxes(out / "data")[1]))
    assert doc["training_camera"]["width"] % 8 == 0 and (out / "eval" / "obj_000001" / "eval.json").is_file()
    assert json.loads((out / "eval_rgb" / "obj_000001" / "eval.json").read_text())["rgb_refined"]
    # the photo-backed held-out frames are those of the photos training holds back: others are refused, not reused
    photos = tmp_path / "photos"
    photos.mkdir()
    for k in range(2):
        cv2.imwrite(str(photos / f"{k}.png"), np.full((60, 80, 3), 60 * k, np.uint8))
    other = subprocess.run([sys.executable, script, "--real", str(real), "--objects", "1", "--frames", "16",
                            "--held-out-frames", "8", "--epochs", "1", "--device", "cpu", "--out", str(out),
                            "--train", f"background_photos={photos}"], capture_output=True, text=True, timeout=300)
    refusal = other.stderr.strip().splitlines()[-1]  # after the library's progress bars: one line, no traceback
    assert other.returncode == 2 and "Traceback" not in other.stderr, other.stderr[-2000:]
    assert refusal.startswith("error: ") and "held_out_photos" in refusal and str(photos) in refusal
    # a zoom network of other fields is refused, not reused in its place
    other_zoom = subprocess.run([sys.executable, script, "--real", str(real), "--objects", "1", "--frames", "16",
                                 "--held-out-frames", "8", "--epochs", "1", "--zoom-epochs", "1", "--device", "cpu",
                                 "--out", str(out), "--zoom-train", "view=colour"],
                                capture_output=True, text=True, timeout=300)
    refusal = other_zoom.stderr.strip().splitlines()[-1]
    assert other_zoom.returncode == 2 and "Traceback" not in other_zoom.stderr, other_zoom.stderr[-2000:]
    assert refusal.startswith("error: ") and "zoom.txt" in refusal
    bad = subprocess.run([sys.executable, script, "--real", str(real), "--objects", "99", "--out",
                          str(tmp_path / "bad")], capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0 and "obj_000099.ply" in bad.stderr
    nowhere = subprocess.run([sys.executable, script, "--real", str(tmp_path / "nowhere"), "--objects", "1", "--out",
                              str(tmp_path / "bad")], capture_output=True, text=True, timeout=300)
    assert nowhere.returncode == 2 and nowhere.stderr.strip().count("\n") == 0 and "nowhere" in nowhere.stderr


@pytest.mark.parametrize("field", ["view=outline", "no_such_field=1", "rotation", "out=elsewhere.pt", "look=outline"])
def test_benchmark_refuses_bad_zoom_fields_in_one_line_before_writing_anything(tmp_path, field):
    out = tmp_path / "bench"
    bad = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "real.py"), "--real", str(tmp_path / "real"),
                          "--objects", "1", "--out", str(out), "--zoom-train", field],
                         capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0, bad.stderr[-2000:]
    assert bad.stderr.startswith("error: ") and field.split("=")[0] in bad.stderr and not out.exists()


def test_a_zoom_record_from_before_a_new_field_is_the_same_fields_and_another_or_a_broken_one_is_refused(
        tmp_path, monkeypatch):
    spec = importlib.util.spec_from_file_location("real_benchmark", ROOT / "benchmarks" / "real.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    trained = []
    monkeypatch.setattr(bench, "train_zoom", lambda cfg: trained.append(cfg))
    zoom = tmp_path / "zoom.pt"
    zoom.write_bytes(b"a finished zoom network")
    cfg = bench.ZoomConfig(data=["data"], object="1", out=str(zoom))
    older = cfg.model_dump()
    del older["occluders"]  # a record written before the field existed: its default then
    zoom.with_suffix(".txt").write_text(json.dumps(older))
    assert bench.trained_zoom(zoom, cfg) == zoom and trained == []  # reused, not trained again
    for record in (json.dumps({**older, "occluders": 0.5}), "{not json"):
        zoom.with_suffix(".txt").write_text(record)
        with pytest.raises(bench.PegasusError, match="zoom.txt"):
            bench.trained_zoom(zoom, cfg)
    assert trained == []

"""benchmarks/refine_rgb.py: the refinement against the RGB image started from the truth, on generated frames."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = str(ROOT / "benchmarks" / "refine_rgb.py")


def test_on_rendered_frames_the_truth_stays_and_a_distance_error_is_mostly_taken_away(dope_dataset, tmp_path):
    out = tmp_path / "figures.json"
    result = subprocess.run([sys.executable, SCRIPT, "--data", str(dope_dataset), "--split", "train_pbr",
                             "--objects", "1", "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    figures = json.loads(out.read_text())["objects"]["1"]
    assert len(result.stdout.strip().splitlines()) == 3
    truth, moved = figures["truth"], figures["distance"]
    # measured: 8 instances; from the truth all within 0.1 d (distance x0.983: the classic render's outline lies
    # about a pixel outside the mesh's); moved along the ray, 0.62 -> 1.00 within 0.1 d, 0.22 of the error left
    assert truth["instances"] == moved["instances"] >= 4
    assert truth["within_0_1d"] == 1.0 and 0.97 < truth["ratio_quartiles"][1] < 1.01
    assert moved["within_0_1d"] > moved["start_within_0_1d"] and moved["distance_error_left"] < 0.5


def test_with_a_zoom_network_its_look_is_measured_from_the_same_starts(dope_dataset, zoom_run, tmp_path):
    out = tmp_path / "figures.json"
    result = subprocess.run([sys.executable, SCRIPT, "--data", str(dope_dataset), "--split", "train_pbr",
                             "--objects", "1", "--zoom", f"1={zoom_run}", "--out", str(out)],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    doc = json.loads(out.read_text())
    figures = doc["objects"]["1"]
    assert len(result.stdout.strip().splitlines()) == 9  # three starts, each taken three ways
    assert doc["rows"]["1 distance"] != doc["rows"]["1 distance zoom"]
    # the zoom network reads the distance from the crop, whatever the start's (measured: -0.10 of the error left,
    # within 0.1 d 0.62 -> 1.00; the refinement after it 0.88)
    zoom = figures["zoom"]["distance"]
    assert zoom["instances"] >= 4 and abs(zoom["distance_error_left"]) < 0.4
    assert zoom["within_0_1d"] > zoom["start_within_0_1d"]
    assert figures["zoom+rgb"]["distance"]["within_0_1d"] >= zoom["start_within_0_1d"]


def test_bad_input_is_one_line_and_exit_code_2(tmp_path):
    for extra in ([], ["--zoom", "2=zoom.pt"], ["--zoom", f"1={tmp_path / 'none.pt'}"]):
        result = subprocess.run([sys.executable, SCRIPT, "--data", str(tmp_path), "--objects", "1", *extra],
                                capture_output=True, text=True, timeout=120)
        assert result.returncode == 2 and result.stderr.count("\n") == 1 and "error:" in result.stderr, result.stderr

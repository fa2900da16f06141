"""Render, info, view, scan-capture and launch under abuse: impossible numbers, absurd sizes, files that are not
what they claim and outputs that are files end with one clear line and exit code 2, before any work or
allocation, and nothing is written."""

import json
import resource
import subprocess
import sys

import cv2
import numpy as np
import pytest
from conftest import random_cloud

from pegasus_gen.cli.main import main
from pegasus_gen.splats.ply import write_ply

PROPS = "x y z f_dc_0 f_dc_1 f_dc_2 opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3".split()
ONE_SPLAT = [0, 0, 0, 0, 0, 0, 0, -3, -3, -3, 1, 0, 0, 0]


def ascii_ply(path, rows, count=None, label=False):
    """An ASCII 3DGS PLY of degree 0 with the given vertex rows (``count``: the vertex count its header
    declares, default len(rows)); with ``label`` an int label is the last property."""
    header = ["ply", "format ascii 1.0", f"element vertex {len(rows) if count is None else count}"]
    header += [f"property float {p}" for p in PROPS] + (["property int label"] if label else []) + ["end_header"]
    path.write_text("\n".join(header + [" ".join(str(v) for v in row) for row in rows]) + "\n")
    return path


def one_line(capsys):
    """The one line of stderr, which must be the error's and no traceback; stdout must be empty."""
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pegasus: error: ") and not captured.out, captured
    return lines[0]


@pytest.fixture
def ply(tmp_path):
    return write_ply(tmp_path / "obj.ply", random_cloud(np.random.default_rng(0), 50, extent=0.2))


def test_a_label_out_of_range_is_one_line_for_info_and_import(tmp_path, capsys):
    bad = ascii_ply(tmp_path / "bad.ply", [ONE_SPLAT + [99999999999]], label=True)
    assert main(["info", str(bad)]) == 2
    assert f"{bad}: vertex line 0: a value out of its property's range" in one_line(capsys)
    library = tmp_path / "lib"
    assert main(["assets", "--library", str(library), "import-splat", str(bad), "--name", "thing", "--kind", "object",
                 "--obj-id", "5"]) == 2
    assert "out of its property's range" in one_line(capsys)
    assert not (library / "thing").exists()


@pytest.mark.parametrize("value, says", [
    ("3e38", "x = 3e+38 is a position beyond 1e+06 m"),
    ("-2e6", "x = -2e+06 is a position beyond 1e+06 m"),
])
def test_absurd_positions_are_refused(tmp_path, capsys, value, says):
    bad = ascii_ply(tmp_path / "far.ply", [ONE_SPLAT, [value] + ONE_SPLAT[1:]])
    assert main(["info", str(bad)]) == 2
    assert f"vertex 1: {says}" in one_line(capsys)


def test_absurd_scales_are_refused(tmp_path, capsys):
    bad = ascii_ply(tmp_path / "huge.ply", [ONE_SPLAT[:8] + [40] + ONE_SPLAT[9:]])  # exp(40) m
    assert main(["info", str(bad)]) == 2
    assert "vertex 0: scale_1 = 40 is a scale of exp(40) beyond 1e+06 m" in one_line(capsys)


def test_a_uint_label_beyond_int32_is_refused(tmp_path, capsys):
    header = ["ply", "format binary_little_endian 1.0", "element vertex 1"]
    header += [f"property float {p}" for p in PROPS] + ["property uint label", "end_header"]
    body = np.array(ONE_SPLAT, "<f4").tobytes() + np.array([2**32 - 1], "<u4").tobytes()
    bad = tmp_path / "label.ply"
    bad.write_bytes(("\n".join(header) + "\n").encode() + body)
    assert main(["info", str(bad)]) == 2
    assert "label 4294967295 is beyond the 32-bit signed integer range" in one_line(capsys)


@pytest.mark.parametrize("text", [False, True], ids=["binary", "ascii"])
def test_an_absurd_vertex_count_is_refused_before_allocating(tmp_path, capsys, text):
    count = 10**12  # terabytes of vertices declared in a file of a few hundred bytes
    if text:
        bad = ascii_ply(tmp_path / "count.ply", [ONE_SPLAT], count=count)
    else:
        header = ["ply", "format binary_little_endian 1.0", f"element vertex {count}"]
        header += [f"property float {p}" for p in PROPS] + ["end_header"]
        bad = tmp_path / "count.ply"
        bad.write_bytes(("\n".join(header) + "\n").encode() + np.array(ONE_SPLAT, "<f4").tobytes())
    assert main(["info", str(bad)]) == 2
    assert f"element 'vertex' declares {count:,} rows, which need at least" in one_line(capsys)


def test_info_on_a_device_or_a_folder_is_refused(tmp_path, capsys):
    assert main(["info", "/dev/zero"]) == 2  # an endless file: it was read until memory ran out
    assert "/dev/zero: not a regular file" in one_line(capsys)
    assert main(["info", str(tmp_path)]) == 2
    assert f"{tmp_path}: not a regular file" in one_line(capsys)


@pytest.mark.parametrize("flags, says", [
    (["--fov", "0"], "--fov must be between 0 and 180"),
    (["--fov", "500"], "--fov must be between 0 and 180"),
    (["--fov", "nan"], "--fov must be between 0 and 180"),
    (["--fx", "nan"], "--fx must be a positive number"),
    (["--fx", "500", "--fy", "-1"], "--fy must be a positive number"),
    (["--cx", "inf"], "--cx must be a finite number"),
    (["--width", "0"], "--width and --height must be positive"),
    (["--eye", "nan", "0", "0"], "--eye must be 3 finite numbers"),
    (["--eye", "0", "0", "1", "--target", "0", "0", "1e300"], "--target must be 3 finite numbers"),
    (["--eye", "0.5", "0.5", "0.5", "--target", "0.5", "0.5", "0.5"], "--eye [0.5, 0.5, 0.5] is the point looked at"),
    (["--background", "5", "-3", "nan"], "--background must be 3 numbers in [0, 1]"),
    (["--width", "200000", "--height", "200000"], "a 200000 x 200000 image needs about 3,200.0 GB of memory"),
])
def test_impossible_render_flags_are_one_line_and_write_nothing(ply, tmp_path, capsys, flags, says):
    out = tmp_path / "out"
    assert main(["render", str(ply), "--out", str(out), "--device", "cpu", *flags]) == 2
    assert says in one_line(capsys)
    assert not out.exists()


def test_a_render_beyond_the_memory_limit_is_refused_before_allocating(ply, tmp_path):
    """Under a 6 GB address-space cap (ulimit -v) a 10000 x 10000 render (about 8 GB) is refused, not killed."""
    def cap():
        resource.setrlimit(resource.RLIMIT_AS, (6 * 10**9, resource.getrlimit(resource.RLIMIT_AS)[1]))

    out = tmp_path / "out"
    result = subprocess.run([sys.executable, "-m", "pegasus_gen.cli", "render", str(ply), "--out", str(out),
                             "--width", "10000", "--height", "10000", "--device", "cpu"],
                            capture_output=True, text=True, preexec_fn=cap, timeout=120)
    assert result.returncode == 2 and not result.stdout, result
    assert result.stderr.startswith("pegasus: error: a 10000 x 10000 image needs about 8.0 GB of memory to render, "
                                    "more than the ") and result.stderr.count("\n") == 1, result.stderr
    assert not out.exists()


def test_scan_capture_of_an_absurd_size_is_refused_before_anything(tmp_path, capsys):
    out = tmp_path / "capture"
    assert main(["scan-capture", str(out), "--size", "60000", "60000"]) == 2
    assert "a 60000 x 60000 image needs about" in one_line(capsys)
    assert main(["scan-capture", str(out), "--size", "0", "360"]) == 2
    assert "a capture needs a positive image size, got 0 x 360" in one_line(capsys)
    assert not out.exists()


def test_an_out_that_is_a_file_is_refused_for_render_and_view(ply, tmp_path, capsys):
    file = tmp_path / "notes.txt"
    file.write_text("keep me")
    assert main(["render", str(ply), "--out", str(file), "--width", "32", "--height", "24", "--device", "cpu"]) == 2
    assert f"--out {file} is a file, not a folder" in one_line(capsys)
    assert main(["render", str(ply), "--out", str(file / "sub"), "--width", "32", "--height", "24"]) == 2
    assert f"--out {file / 'sub'}: {file} is a file, not a folder" in one_line(capsys)
    assert main(["view", str(tmp_path), "--out", str(file)]) == 2
    assert f"--out {file} is a file, not a folder" in one_line(capsys)
    assert file.read_text() == "keep me"


def tiny_bop(root, cam_K=(500, 0, 16, 0, 500, 12, 0, 0, 1), cam_t=(0, 0, 300)):
    """A BOP dataset of one 32 x 24 image with one instance of obj 1 (a 20 mm cube) at ``cam_t`` (mm)."""
    scene = root / "train_pbr" / "000000"
    (scene / "rgb").mkdir(parents=True)
    (root / "models").mkdir()
    (root / "models" / "models_info.json").write_text(json.dumps(
        {"1": {"min_x": -10, "min_y": -10, "min_z": -10, "size_x": 20, "size_y": 20, "size_z": 20}}))
    cv2.imwrite(str(scene / "rgb" / "000000.png"), np.full((24, 32, 3), 90, np.uint8))
    (scene / "scene_gt.json").write_text(json.dumps(
        {"0": [{"obj_id": 1, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": list(cam_t)}]}))
    (scene / "scene_camera.json").write_text(json.dumps({"0": {"cam_K": list(cam_K), "depth_scale": 1.0}}))
    return root


@pytest.mark.parametrize("damage, says", [
    ({}, None),
    ({"cam_t": (float("nan"), 0, 300)}, "image 0: instance 0: cam_R_m2c / cam_t_m2c are not finite"),
    ({"cam_K": (0,) * 9}, "image 0: cam_K [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0] is not a camera matrix"),
    ({"cam_K": (500, 0, 16, 0, float("inf"), 12, 0, 0, 1)}, "is not a camera matrix"),
])
def test_view_refuses_nan_poses_and_a_zero_camera_matrix(tmp_path, capsys, damage, says):
    root = tiny_bop(tmp_path / "ds", **damage)
    out = tmp_path / "view"
    code = main(["view", str(root), "--out", str(out)])
    if says is None:  # the undamaged dataset is drawn
        assert code == 0 and (out / "index.html").is_file() and (out / "000000_000000.jpg").is_file()
        return
    assert code == 2
    assert says in one_line(capsys)
    assert not out.exists()


def test_a_file_that_is_not_a_launch_file_is_one_line(tmp_path, capsys):
    config = tmp_path / "cfg.yaml"
    config.write_text("scenes: 3\n")
    assert main(["launch", str(config)]) == 2
    assert f"{config}: not a launch file" in one_line(capsys)
    broken = tmp_path / "broken.launch.py"
    broken.write_text("def generate_launch_description(:\n    pass\n")
    assert main(["launch", str(broken)]) == 2
    assert f"{broken}: line 1: invalid syntax" in one_line(capsys)


def test_an_error_is_one_line_without_pybullet_banner(tmp_path):
    """`pegasus generate` imports PyBullet, whose C module prints its build time on import."""
    result = subprocess.run([sys.executable, "-m", "pegasus_gen.cli", "generate", f"output={tmp_path / 'ds'}",
                             "no_such_key=1"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and not result.stdout, result
    assert result.stderr.startswith("pegasus: error: ") and result.stderr.count("\n") == 1, result.stderr

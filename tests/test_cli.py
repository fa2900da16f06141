"""The pegasus command line: outputs appear, bad input gives one clear message and a non-zero exit."""

import subprocess
import sys

import cv2
import numpy as np
import pytest
from conftest import random_cloud

from pegasus_gen.cli.main import main
from pegasus_gen.splats.ply import write_ply


def test_demo_writes_images_and_scene(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--library", str(tmp_path / "lib"), "--device", "cpu"]) == 0
    printed = capsys.readouterr().out
    assert str(tmp_path / "overview.png") in printed
    rgb = cv2.imread(str(tmp_path / "rgb.png"))
    assert rgb.shape == (480, 640, 3) and rgb.std() > 10  # a real picture, not a blank canvas
    depth = cv2.imread(str(tmp_path / "depth_mm.png"), cv2.IMREAD_UNCHANGED)
    assert depth.dtype == np.uint16 and 300 < np.median(depth[depth > 0]) < 3000  # table 0.3..3 m away
    assert (tmp_path / "scene.ply").stat().st_size > 0


def test_render_command_frames_a_ply(tmp_path, capsys):
    cloud = random_cloud(np.random.default_rng(0), 500, center=(5.0, 2.0, 1.0), extent=0.3)
    ply = write_ply(tmp_path / "obj.ply", cloud)
    out = tmp_path / "out"
    assert main(["render", str(ply), "--out", str(out), "--width", "96", "--height", "64", "--device", "cpu"]) == 0
    rgb = cv2.imread(str(out / "rgb.png"))
    assert rgb.shape == (64, 96, 3)
    assert (rgb.sum(axis=2) > 0).mean() > 0.1  # auto-framing put the object in view
    assert main(["info", str(ply)]) == 0
    assert "500 splats, SH degree 3" in capsys.readouterr().out


def test_bad_ply_is_one_clear_error_without_output(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_text("hello")
    out = tmp_path / "out"
    result = subprocess.run([sys.executable, "-m", "pegasus_gen.cli", "render", str(bad), "--out", str(out)],
                            capture_output=True, text=True)
    assert result.returncode == 2
    assert f"{bad}: not a PLY file" in result.stderr and "Traceback" not in result.stderr
    assert not out.exists()


@pytest.mark.parametrize("flags", [["--width", "0"], ["--fov", "0"], ["--fx", "-3"]])
def test_bad_camera_flags_are_rejected(tmp_path, capsys, flags):
    assert main(["render", str(tmp_path / "x.ply"), *flags]) == 2  # before the file is even looked for
    assert capsys.readouterr().err.startswith(f"pegasus: error: {flags[0]}")


def test_assets_import_list_show(tmp_path, capsys):
    import trimesh

    mesh = trimesh.creation.box((60, 40, 30))  # millimetres
    mesh.export(tmp_path / "box.stl")
    lib = str(tmp_path / "lib")
    assert main(["assets", "--library", lib, "import-mesh", str(tmp_path / "box.stl"), "--name", "box",
                 "--kind", "object", "--obj-id", "4", "--scale", "0.001"]) == 0
    assert main(["assets", "--library", lib, "list"]) == 0
    assert "box" in capsys.readouterr().out
    assert main(["assets", "--library", lib, "show", "4", "--out", str(tmp_path / "prev"), "--device", "cpu"]) == 0
    printed = capsys.readouterr().out
    ious = [float(v) for v in printed.split("IoU per view:")[1].split("\n")[0].split()]
    assert len(ious) == 6 and min(ious) > 0.9
    preview = cv2.imread(str(tmp_path / "prev" / "box_turntable.png"))
    assert preview.shape == (360, 1440, 3)
    assert main(["assets", "--library", lib, "show", "nothing"]) == 2
    assert "no asset 'nothing'" in capsys.readouterr().err

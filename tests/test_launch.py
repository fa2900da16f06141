"""Launch files without ROS: arguments declared, overridden and substituted into node parameters; nodes
built and spun until done; bad arguments are clear errors."""

import cv2
import numpy as np
import pytest

from nodes.launch import run
from pegasus_gen.cli.main import main
from pegasus_gen.errors import PegasusError

LAUNCH = '''
from nodes.launch import DeclareLaunchArgument, LaunchConfiguration, LaunchDescription, Node


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("images", description="image folder"),
        DeclareLaunchArgument("rate", default_value="100.0"),
        DeclareLaunchArgument("source", default_value="folder", choices=["folder", "oak"]),
        Node(package="pegasus", executable="camera_node",
             parameters=[{"source": LaunchConfiguration("source"), "folder": LaunchConfiguration("images"),
                          "rate": LaunchConfiguration("rate"), "loop": False, "fx": 500.0}]),
    ])
'''


@pytest.fixture
def launch_file(tmp_path):
    path = tmp_path / "camera.launch.py"
    path.write_text(LAUNCH)
    images = tmp_path / "images"
    images.mkdir()
    for k in range(3):
        cv2.imwrite(str(images / f"{k:03d}.png"), np.full((24, 32, 3), 40 * k, np.uint8))
    return path, images


def test_launch_runs_its_nodes_with_overridden_arguments(launch_file):
    path, images = launch_file
    (camera,) = run(path, [f"images:={images}", "rate:=200"])
    assert camera.frames == 3 and camera.get_parameter("rate").value == 200
    assert camera.get_parameter("folder").value == str(images)
    K = camera.camera_matrix(32, 24)
    assert K[0, 0] == 500.0 and K[0, 2] == 15.5


def test_bad_launch_arguments_are_clear_errors(launch_file, tmp_path, capsys):
    path, images = launch_file
    with pytest.raises(PegasusError, match=r"unknown launch argument\(s\) colour \(declared: images, rate, source\)"):
        run(path, [f"images:={images}", "colour:=red"])
    with pytest.raises(PegasusError, match="'images' has no default"):
        run(path, [])
    with pytest.raises(PegasusError, match="source:=usb is not one of folder, oak"):
        run(path, [f"images:={images}", "source:=usb"])
    assert main(["launch", str(path), "images=oops"]) == 2
    assert "is not of the form name:=value" in capsys.readouterr().err
    assert main(["launch", str(path), f"images:={tmp_path / 'empty'}"]) == 2
    assert "no images" in capsys.readouterr().err


def test_generate_train_deploy_launch_runs_the_whole_loop(library, tmp_path, monkeypatch):
    monkeypatch.setenv("PEGASUS_ASSETS", str(library.root))
    out = tmp_path / "loop"
    nodes = run("launch/generate_train_deploy.launch.py",
                [f"output:={out / 'ds'}", f"run:={out / 'run'}", "scenes:=1", "frames:=3", "width:=160",
                 "height:=120", "epochs:=1", "device:=cpu", f"images:={out / 'ds' / 'train_pbr' / '000000' / 'rgb'}",
                 "max_images:=2"], timeout=300)
    by_name = {n.get_name(): n for n in nodes}
    assert by_name["inference_node"].images == 2 and by_name["inference_node"].model is not None
    assert (out / "run" / "model.onnx").is_file() and len(list((out / "ds" / "train_pbr").glob("*/rgb/*"))) == 3


def test_shipped_launch_files_parse_and_name_their_required_arguments():
    with pytest.raises(PegasusError, match="'host' has no default"):
        run("launch/ur5_pick_place.launch.py", [])
    from nodes.launch import load_description, resolve_arguments

    for name in ("generate_train_deploy", "sim_pick_place", "ur5_pick_place"):
        description = load_description(f"launch/{name}.launch.py")
        assert any(type(e).__name__ == "Node" for e in description.entities)
    args = resolve_arguments(load_description("launch/sim_pick_place.launch.py"), {"attempts": "3"})
    assert args["attempts"] == "3" and args["pose_source"] == "dope"

"""Launch files without ROS: arguments declared, overridden and substituted into node parameters; nodes
built and spun until done; bad arguments are clear errors."""

import cv2
import numpy as np
import pytest

from nodes.launch import run
from pegasus_gen.cli.main import main
from pegasus_gen.errors import PegasusError

LAUNCH = '''
from nodes.launch import DeclareLaunchArgument, LaunchConfiguration, LaunchDescription, Node, Shutdown


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("images", description="image folder"),
        DeclareLaunchArgument("rate", default_value="100.0"),
        DeclareLaunchArgument("source", default_value="folder", choices=["folder", "oak"]),
        Node(package="pegasus", executable="camera_node", on_exit=Shutdown(),
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
    (camera,) = run(path, [f"images:={images}", "rate:=200.0"])
    assert camera.frames == 3 and camera.get_parameter("rate").value == 200.0
    assert camera.get_parameter("folder").value == str(images)
    K = camera.camera_matrix(32, 24)
    assert K[0, 0] == 500.0 and K[0, 2] == 15.5


def test_a_node_ends_the_launch_only_through_on_exit_shutdown(tmp_path):
    # as under ros2 launch: each node ends alone (its own context shut down, nodes.ros.finish); the launch
    # goes on until a node whose action has on_exit=Shutdown() ends
    folders = []
    for n in (2, 6):
        folders.append(tmp_path / f"images{n}")
        folders[-1].mkdir()
        for k in range(n):
            cv2.imwrite(str(folders[-1] / f"{k:03d}.png"), np.full((8, 8, 3), 10 * k, np.uint8))
    path = tmp_path / "two.launch.py"
    path.write_text(f'''
from nodes.launch import LaunchDescription, Node, Shutdown


def generate_launch_description():
    return LaunchDescription([
        Node(package="pegasus", executable="camera_node",
             parameters=[{{"folder": "{folders[0]}", "rate": 100.0, "loop": False, "fx": 10.0}}]),
        Node(package="pegasus", executable="camera_node", on_exit=Shutdown(),
             parameters=[{{"folder": "{folders[1]}", "rate": 20.0, "loop": False, "fx": 10.0}}]),
    ])
''')
    short, long = run(path, [], timeout=60)
    assert (short.frames, long.frames) == (2, 6)
    assert not short.context.running and not long.context.running


def test_bad_launch_arguments_are_clear_errors(launch_file, tmp_path, capsys):
    path, images = launch_file
    with pytest.raises(PegasusError, match=r"unknown launch argument\(s\) colour \(declared: images, rate, source\)"):
        run(path, [f"images:={images}", "colour:=red"])
    with pytest.raises(PegasusError, match="'images' has no default"):
        run(path, [])
    with pytest.raises(PegasusError, match="source:=usb is not one of folder, oak"):
        run(path, [f"images:={images}", "source:=usb"])
    with pytest.raises(PegasusError, match="camera_node: .*'rate' to '200' of type 'INTEGER', expecting type 'DOUBLE'"):
        run(path, [f"images:={images}", "rate:=200"])  # YAML reads 200 as an int, as launch_ros does
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


def test_parameter_values_follow_launch_ros_rules():
    from typing import List

    from nodes.launch import LaunchConfiguration as Arg
    from nodes.launch import ParameterValue, parameter_value

    def value(v, text):
        return parameter_value("p", v, {"a": text})

    # a launch argument's text by YAML rules; '' stays a string; a list of one type becomes a tuple
    assert [value(Arg("a"), t) for t in ("", "4", "0.1", "true", "cup", "[a, b]")] == \
        ["", 4, 0.1, True, "cup", ("a", "b")]
    for bad in ("[1, 0.5]", "[{asset: cup}]", "[]", "{a: 1}"):
        with pytest.raises(PegasusError, match="parameter p"):
            value(Arg("a"), bad)
    # ParameterValue coerces: float from an int's text, str kept verbatim, List[float] needs floats
    assert value(ParameterValue(Arg("a"), value_type=float), "1") == 1.0
    assert value(ParameterValue(Arg("a"), value_type=str), "[{asset: cup}]") == "[{asset: cup}]"
    assert value(ParameterValue(Arg("a"), value_type=List[float]), "[1.0, -2.5]") == (1.0, -2.5)
    for bad_type, text in ((List[float], "[1, 2.5]"), (List[float], "1.0 2.5"), (int, "1.5"), (bool, "yes please")):
        with pytest.raises(PegasusError, match="parameter p"):
            value(ParameterValue(Arg("a"), value_type=bad_type), text)
    assert value([1, 0.5], "") == (1.0, 0.5) and value(["a", "b"], "") == ("a", "b")


EYE = "[" + ", ".join(f"{v:.1f}" for v in np.eye(4).ravel()) + "]"
SHIPPED = [("generate_train_deploy", []), ("generate_train_deploy", ["scenes:=2", "environments:=[wooden_table]",
                                                                       "objects_config:=[{asset: cup, count: 1}]",
                                                                       "train_options:=focal_px=330 schedule=cosine"]),
           ("sim_pick_place", ["model:=m.onnx"]), ("sim_pick_place", ["objects:=a,b", "time_scale:=2", "attempts:=3"]),
           ("ur5_pick_place", ["host:=10.0.0.2", "model:=m.onnx", f"hand_eye:={EYE}", "speed:=1", "dry_run:=false"]),
           ("ur5_pick_place", ["host:=10.0.0.2", "model:=m.onnx", f"hand_eye:={EYE}", "refine_rgb:=obj_000001.ply",
                               "mesh_scale:=0.001", "use_pose:=refined"])]


@pytest.mark.parametrize("name,args", SHIPPED)
def test_shipped_launch_files_pass_each_node_the_types_it_declares(name, args):
    # launch_ros's evaluation of each Node action's parameters, declared as the node declares them (static
    # types, as rclpy): every value has its parameter's type and every parameter passed is one the node has
    import importlib

    from nodes import compat
    from nodes.launch import Node, load_description, parameter_value, parse_overrides, resolve_arguments
    from nodes.ros import declare

    description = load_description(f"launch/{name}.launch.py")
    arguments = resolve_arguments(description, parse_overrides(args))
    for action in (e for e in description.entities if isinstance(e, Node)):
        table = importlib.import_module(f"nodes.{action.executable}").PARAMETERS
        given = {k: parameter_value(k, v, arguments) for group in action.parameters for k, v in group.items()}
        assert set(given) <= {k for k, _ in table}, (action.executable, set(given) - {k for k, _ in table})
        node = compat.Node(action.executable, parameter_overrides=[compat.Parameter(k, value=v)
                                                                    for k, v in given.items()])
        values = declare(node, table)
        assert all(values[k] == v for k, v in given.items())


def test_values_of_another_type_than_declared_are_refused():
    from nodes import compat
    from nodes.camera_node import PARAMETERS as CAMERA
    from nodes.generator_node import PARAMETERS as GENERATOR
    from nodes.robot_node import PARAMETERS as ROBOT
    from nodes.ros import declare

    for table, name, value in ((GENERATOR, "scenes", "4"), (ROBOT, "hand_eye", "1 0 0 0"), (ROBOT, "speed", 1),
                               (CAMERA, "width", 640.0), (GENERATOR, "overrides", ["scenes=2"])):
        node = compat.Node("n", parameter_overrides=[compat.Parameter(name, value=value)])
        with pytest.raises(compat.InvalidParameterTypeException, match=name):
            declare(node, table)
    from nodes.launch import Node, load_description, parameter_value

    description = load_description("launch/ur5_pick_place.launch.py")
    robot = next(e for e in description.entities if isinstance(e, Node) and e.executable == "robot_node")
    with pytest.raises(PegasusError, match="hand_eye"):  # the old text form of the matrix
        parameter_value("hand_eye", robot.parameters[0]["hand_eye"], {"hand_eye": "1 0 0 0.2"})

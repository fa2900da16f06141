"""Nodes of the stack under real rclpy (PEGASUS_ROS=rclpy: the ROS 2 Jazzy wheels of the ros extra, Fast DDS), each
in a process of its own talking to this test's own rclpy node on a DDS domain of this test process's own:
camera_node plays an image folder (what arrives is the folder's images with their CameraInfo); TF and
detections travel in the message packages nodes.ros_interfaces builds. Skipped without the wheels."""

import os
import signal
import subprocess
import sys

import cv2
import numpy as np
import pytest
from conftest import ROS_DOMAIN_ID, ros_implementation, spin_until

from nodes.conversions import image_to_numpy


def node_env() -> dict:
    return {**os.environ, "PEGASUS_ROS": "rclpy", "ROS_DOMAIN_ID": str(ROS_DOMAIN_ID),
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}


def test_camera_node_publishes_a_folder_over_dds_to_another_process(tmp_path):
    ros = ros_implementation("rclpy")
    rng = np.random.default_rng(3)
    images = [rng.integers(0, 256, (24, 32, 3), dtype=np.uint8) for _ in range(3)]
    for k, rgb in enumerate(images):
        cv2.imwrite(str(tmp_path / f"{k:02d}.png"), rgb[..., ::-1])
    ros.init()
    node = subprocess.Popen(
        [sys.executable, "-c", "from nodes.camera_node import main; main()", "--ros-args", "-p",
         f"folder:={tmp_path}", "-p", "rate:=20.0", "-p", "fx:=30.0", "-p", "frame_id:=cam"],
        env=node_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        probe = ros.Node("probe")
        got = {"image": [], "camera_info": []}
        for topic, type_name in (("image", "sensor_msgs/msg/Image"), ("camera_info", "sensor_msgs/msg/CameraInfo")):
            probe.create_subscription(ros.message(type_name), topic, got[topic].append, 10)
        executor = ros.SingleThreadedExecutor()
        executor.add_node(probe)
        arrived = spin_until(executor, lambda: len(got["image"]) >= 4 and len(got["camera_info"]) >= 4, timeout=90)
        assert arrived, (got, node.poll(), node.stderr.read() if node.poll() is not None else "")
        # the graph names a remote node once its discovery info arrives, which may come after its first messages
        # (until then rmw reports _NODE_NAME_UNKNOWN_)
        expected = [("camera_node", "sensor_msgs/msg/Image")]

        def publishers():
            return [(p.node_name, p.topic_type) for p in probe.get_publishers_info_by_topic("image")]
        spin_until(executor, lambda: publishers() == expected, timeout=30)
        assert publishers() == expected
    finally:
        node.send_signal(signal.SIGINT)
        out, err = node.communicate(timeout=30)
        ros.rclpy.shutdown()
    assert node.returncode == 0 and "Traceback" not in err, err  # Ctrl-C ends it cleanly
    # each image is one of the folder's, in the folder's order, with its CameraInfo (same stamp, K from fx)
    index = [next(k for k, rgb in enumerate(images) if np.array_equal(image_to_numpy(msg), rgb))
             for msg in got["image"]]
    assert all((b - a) % 3 == 1 for a, b in zip(index, index[1:])), index
    stamps = {(m.header.stamp.sec, m.header.stamp.nanosec) for m in got["image"]}
    for info in got["camera_info"]:
        assert (info.width, info.height, info.header.frame_id, info.distortion_model) == (32, 24, "cam", "plumb_bob")
        np.testing.assert_array_equal(np.array(info.k).reshape(3, 3), [[30, 0, 15.5], [0, 30, 11.5], [0, 0, 1]])
    assert len(stamps & {(m.header.stamp.sec, m.header.stamp.nanosec) for m in got["camera_info"]}) >= 3


def test_a_node_that_needs_a_package_without_a_wheel_says_which():
    """tf2_msgs and vision_msgs have no wheels: where nodes.ros_interfaces has not built them (here: hidden from
    the import system, with tf2_ros), under PEGASUS_ROS=rclpy the nodes that need them refuse to start, naming
    the package."""
    pytest.importorskip("rclpy", reason="real rclpy comes with the ros extra (pip install '.[ros]')")
    probe = ("import sys\nfor name in ('tf2_ros', 'tf2_msgs', 'tf2_msgs.msg', 'vision_msgs', 'vision_msgs.msg'):\n"
             "    sys.modules[name] = None  # not installed\n"
             "import nodes.ros as r\nassert r.REAL_ROS and r.rclpy.__name__ == 'rclpy'\n"
             "from nodes.inference_node import InferenceNode\nfrom nodes.robot_node import RobotNode\n"
             "r.rclpy.init()\nfor make in (RobotNode, InferenceNode):\n    try:\n        make()\n"
             "    except ImportError as exc:\n        print(exc)\n")
    result = subprocess.run([sys.executable, "-c", probe], env=node_env(), capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    advice = ("which has no wheel: build it into this environment (python -m nodes.ros_interfaces), run in a ROS 2 "
              "install or on the stand-in (PEGASUS_ROS=stand-in)")
    assert result.stdout.splitlines() == [f"StaticTransformBroadcaster needs ROS 2's tf2_msgs, {advice}",
                                          f"Detection3DArray needs ROS 2's vision_msgs, {advice}"]


def test_the_built_message_packages_carry_tf_and_detections_between_processes():
    """tf2_msgs and vision_msgs as nodes.ros_interfaces builds them: a StaticTransformBroadcaster (nodes.ros's,
    tf2_ros having no wheel) and a Detection3DArray publisher in another process reach this one over DDS."""
    ros = ros_implementation("rclpy")
    pytest.importorskip("tf2_msgs", reason="built by python -m nodes.ros_interfaces (make's set-up)")
    pytest.importorskip("vision_msgs", reason="built by python -m nodes.ros_interfaces (make's set-up)")
    sender = ("import time\nimport nodes.ros as r\nr.rclpy.init()\nnode = r.Node('sender')\n"
              "tf = r.StaticTransformBroadcaster(node)\n"
              "tf.sendTransform(r.msgs.TransformStamped(child_frame_id='camera'))\n"
              "pub = node.create_publisher(r.msgs.Detection3DArray, 'detections', 5)\n"
              "while r.rclpy.ok():\n"
              "    pub.publish(r.msgs.Detection3DArray(detections=[r.msgs.Detection3D(id='cup_0')]))\n"
              "    r.rclpy.spin_once(node, timeout_sec=0.1)\n")
    ros.init()
    process = subprocess.Popen([sys.executable, "-c", sender], env=node_env(), stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        probe, got = ros.Node("probe"), {"tf": [], "detections": []}
        latched = ros.QoSProfile(depth=1, durability=ros.DurabilityPolicy.TRANSIENT_LOCAL)
        probe.create_subscription(ros.message("tf2_msgs/msg/TFMessage"), "/tf_static", got["tf"].append, latched)
        probe.create_subscription(ros.message("vision_msgs/msg/Detection3DArray"), "detections",
                                  got["detections"].append, 5)
        executor = ros.SingleThreadedExecutor()
        executor.add_node(probe)
        assert spin_until(executor, lambda: got["tf"] and got["detections"], timeout=60), process.poll()
    finally:
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=30)
        ros.rclpy.shutdown()
    assert [t.child_frame_id for t in got["tf"][0].transforms] == ["camera"]
    assert got["detections"][0].detections[0].id == "cup_0"


def test_pegasus_launch_processes_runs_each_node_as_a_process_on_the_real_rclpy(tmp_path, monkeypatch, capsys):
    from pegasus_gen.cli.main import main

    ros_implementation("rclpy")
    images = tmp_path / "images"
    images.mkdir()
    for k in range(3):
        cv2.imwrite(str(images / f"{k:03d}.png"), np.full((24, 32, 3), 40 * k, np.uint8))
    path = tmp_path / "camera.launch.py"
    path.write_text('''
from nodes.launch import DeclareLaunchArgument, LaunchConfiguration, LaunchDescription, Node, Shutdown

def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("images"),
        Node(package="pegasus", executable="camera_node", on_exit=Shutdown(),
             parameters=[{"folder": LaunchConfiguration("images"), "rate": 50.0, "loop": False, "fx": 500.0}]),
    ])
''')
    for key, value in node_env().items():
        monkeypatch.setenv(key, value)
    logs = tmp_path / "logs"
    assert main(["launch", "--processes", "--log-dir", str(logs), str(path), f"images:={images}"]) == 0
    assert "camera_node exited 0" in capsys.readouterr().out
    assert (logs / "camera_node.log").is_file()
    (tmp_path / "empty").mkdir()  # the node process gets the parameters: it refuses a folder without images
    assert main(["launch", "--processes", "--log-dir", str(logs), str(path), f"images:={tmp_path / 'empty'}"]) == 1
    assert "camera_node exited 2" in capsys.readouterr().out  # one line, as a CLI's bad input
    assert (logs / "camera_node.log").read_text().startswith("error: camera_node: no images")
    assert main(["launch", "--processes", str(path), "images=oops"]) == 2  # bad input: one line, code 2
    assert "is not of the form name:=value" in capsys.readouterr().err

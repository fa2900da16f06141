"""The closed loop in simulation: sim_pick_place.launch.py through `pegasus sim-grasp`: a simulated cell,
splat-rendered camera images, robot node through ur-rtde, evaluator with report and strip."""

import json
import os

import cv2
import numpy as np
from bag_reader import read_bag

from pegasus_gen.assets.demo_library import build_demo_library
from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.cli.main import main


def test_sim_grasp_with_true_poses_puts_every_cup_in_the_basket(tmp_path, capsys):
    lib = AssetLibrary(tmp_path / "lib")
    build_demo_library(lib)
    host = f"127.0.{os.getpid() % 200 + 20}.202"
    assert main(["sim-grasp", "--ground-truth", "--attempts", "3", "--objects", "noodle_cup_red,noodle_cup_curry",
                 "--library", str(lib.root), "--host", host, "--time-scale", "3", "--device", "cpu",
                 "--out", str(tmp_path / "report"), "--record", str(tmp_path / "episode.mcap")]) == 0
    report = json.loads((tmp_path / "report" / "report.json").read_text())
    assert report["attempts"] == 3 and report["successes"] == 3 and report["pose_source"] == "ground_truth"
    assert [r["object"] for r in report["records"]] == ["noodle_cup_red", "noodle_cup_curry", "noodle_cup_red"]
    assert all(r["adds_m"] < 1e-6 for r in report["records"])
    assert cv2.imread(str(tmp_path / "report" / "strip.png")).shape[1] == 5 * 320
    assert "3 of 3 in the basket" in capsys.readouterr().out

    # the episode's bag: every topic of the cell, with its ROS 2 type, decodable from the bag alone
    bag = read_bag(tmp_path / "episode")
    types = {topic: kind for topic, (kind, _) in bag.items()}
    assert {"/image": "sensor_msgs/msg/Image", "/depth": "sensor_msgs/msg/Image",
            "/camera_info": "sensor_msgs/msg/CameraInfo", "/tf_static": "tf2_msgs/msg/TFMessage",
            "/robot_status": "std_msgs/msg/String", "/attempt": "std_msgs/msg/String",
            "/object_pose": "geometry_msgs/msg/PoseStamped"}.items() <= types.items()
    images, depths = bag["/image"][1], bag["/depth"][1]
    assert len(images) >= 3 and abs(len(images) - len(depths)) <= 1
    assert abs(len(images) - len(bag["/camera_info"][1])) <= 1
    stamp = lambda m: m.header.stamp.sec * 10**9 + m.header.stamp.nanosec  # noqa: E731
    for topic in ("/image", "/depth", "/camera_info", "/robot_status"):
        assert np.all(np.diff([t for t, _ in bag[topic][1]]) >= 0), topic  # receive stamps in order
    assert np.all(np.diff([stamp(m) for _, m in images]) > 0)
    assert {stamp(m) for _, m in depths} <= {stamp(m) for _, m in images} | {stamp(m) for _, m in depths[-1:]}
    first = images[0][1]
    assert (first.width, first.height, first.encoding, len(first.data)) == (640, 480, "rgb8", 640 * 480 * 3)
    assert depths[0][1].encoding == "32FC1"
    assert {t.child_frame_id for _, m in bag["/tf_static"][1] for t in m.transforms} >= {"base_link", "camera"}
    attempts = [json.loads(m.data)["attempt"] for _, m in bag["/attempt"][1]]
    assert attempts == [0, 1, 2]  # the evaluator's, in order
    assert {json.loads(m.data)["attempt"] for _, m in bag["/robot_status"][1]} == set(attempts)


def test_sim_grasp_without_a_model_is_a_clear_error(capsys):
    assert main(["sim-grasp"]) == 2
    assert "--model" in capsys.readouterr().err

"""The node chain under real rclpy: sim_pick_place with ground-truth poses and 3 attempts, every node a process
of its own (``nodes.launch.run_processes``: PEGASUS_ROS=rclpy, Fast DDS on a domain of this test's own), with
the evaluator's report and a rosbag2 recording; then the same launch on the stand-in (``nodes.launch.run``, one
process). Both score 3 of 3, and their bags agree on what was published: the same topics with the same types
(real ROS 2 adds /rosout and /parameter_events), the same counts within one for the topics the episode's
events drive; the camera's count follows the episode's length, which differs."""

import json
import os

import pytest
from bag_reader import read_bag
from conftest import ros_implementation

from nodes.launch import find_launch_file, run, run_processes

pytestmark = pytest.mark.slow

EVENT_TOPICS = ("/attempt", "/robot_status", "/tf_static")  # what attempts, not time, decide
ROS2_ONLY = {"/rosout": "rcl_interfaces/msg/Log", "/parameter_events": "rcl_interfaces/msg/ParameterEvent"}


def episode(library, out, host):
    return ["pose_source:=ground_truth", "attempts:=3", "objects:=noodle_cup_red,noodle_cup_curry",
            f"library:={library.root}", f"host:={host}", "time_scale:=3", "device:=cpu", f"report:={out / 'report'}",
            f"record:={out / 'episode'}"]


def test_sim_pick_place_under_real_rclpy_in_separate_processes_matches_the_stand_in(library, tmp_path):
    from conftest import ROS_DOMAIN_ID

    ros_implementation("rclpy")  # skips without the ros extra
    for package in ("tf2_msgs", "vision_msgs"):
        pytest.importorskip(package, reason="built by python -m nodes.ros_interfaces (make's set-up)")
    launch = find_launch_file("sim_pick_place.launch.py")
    real, standin = tmp_path / "real", tmp_path / "stand-in"
    real.mkdir()
    codes = run_processes(launch, episode(library, real, f"127.0.{os.getpid() % 200 + 20}.203"),
                          env={"ROS_DOMAIN_ID": str(ROS_DOMAIN_ID), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"},
                          timeout=400, log_dir=real)
    logs = {name: (real / f"{name}.log").read_text() for name in codes}
    assert codes == dict.fromkeys(codes, 0), logs  # each ended cleanly, the last ones on Ctrl-C
    assert set(codes) == {"sim_controller_node", "camera_node", "inference_node", "robot_node", "evaluator_node",
                          "recorder_node"}
    run(launch, episode(library, standin, f"127.0.{os.getpid() % 200 + 20}.204"), timeout=400)

    reports = {name: json.loads((out / "report" / "report.json").read_text()) for name, out in
               (("real", real), ("stand-in", standin))}
    for name, report in reports.items():
        assert (report["attempts"], report["successes"], report["pose_source"]) == (3, 3, "ground_truth"), name
        assert [r["object"] for r in report["records"]] == ["noodle_cup_red", "noodle_cup_curry", "noodle_cup_red"]
    # rosbags' reader refuses real rclpy's /parameter_events (Fast CDR ends them in more padding than it takes):
    # only EVENT_TOPICS are decoded, the others counted
    bags = {"real": read_bag(real / "episode", EVENT_TOPICS), "stand-in": read_bag(standin / "episode", EVENT_TOPICS)}
    types = {name: {topic: kind for topic, (kind, _) in bag.items()} for name, bag in bags.items()}
    assert types["real"] == types["stand-in"] | ROS2_ONLY
    counts = {name: {topic: len(messages) for topic, (_, messages) in bag.items()} for name, bag in bags.items()}
    for topic in EVENT_TOPICS:
        assert abs(counts["real"][topic] - counts["stand-in"][topic]) <= 1, (topic, counts)
    assert [json.loads(m.data)["attempt"] for _, m in bags["real"]["/attempt"][1]] == [0, 1, 2]
    assert {t.child_frame_id for _, m in bags["real"]["/tf_static"][1] for t in m.transforms} >= {"base_link",
                                                                                                   "camera"}
    for name, count in counts.items():  # each frame's image, depth and camera_info, in both
        assert count["/image"] >= 3 and abs(count["/image"] - count["/depth"]) <= 1, (name, count)
        assert abs(count["/image"] - count["/camera_info"]) <= 1, (name, count)

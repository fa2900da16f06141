"""rosbag2 episodes: recorder_node writes every topic of the graph into an MCAP bag that an independent
reader (rosbags) reads back, decoding each message with only the definitions the bag itself carries (as
Foxglove does): types, counts, QoS, stamps, contents."""

import numpy as np
import pytest
from bag_reader import read_bag
from rosbags.rosbag2 import Reader

from nodes.bag import bag_directory
from nodes.compat import QoSProfile, ReliabilityPolicy
from nodes.conversions import matrix_to_pose_msg, numpy_to_image
from nodes.recorder_node import RecorderNode
from nodes.ros import REAL_ROS, Node, Parameter, SingleThreadedExecutor, latched, msgs, rclpy
from pegasus_gen.errors import PegasusError

pytestmark = pytest.mark.skipif(REAL_ROS, reason="drives the stand-in graph; with ROS 2 use ros2 bag")


def test_the_recorder_writes_every_topic_with_its_type_and_qos(tmp_path):
    rclpy.init()
    try:
        source = Node("source")
        status = source.create_publisher(msgs.String, "robot_status", latched())
        status.publish(msgs.String(data="before the recorder"))  # reaches it through transient local
        images = source.create_publisher(msgs.Image, "image",
                                         QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT))
        poses = source.create_publisher(msgs.PoseStamped, "object_pose", 5)
        detections = source.create_publisher(msgs.Detection3DArray, "detections", 5)
        recorder = RecorderNode(parameter_overrides=[Parameter("path", value=str(tmp_path / "ep.mcap"))])
        executor = SingleThreadedExecutor()
        executor.add_node(recorder)
        executor.spin_once(0.05)
        for k in range(4):
            header = msgs.Header(frame_id="camera")
            header.stamp = source.get_clock().now().to_msg()
            images.publish(numpy_to_image(np.full((2, 3, 3), k, np.uint8), "rgb8", header))
            T = np.eye(4)
            T[:3, 3] = [0.1 * k, 0.0, 0.5]
            poses.publish(msgs.PoseStamped(header=header, pose=matrix_to_pose_msg(T)))
            detections.publish(msgs.Detection3DArray(header=header, detections=[msgs.Detection3D(id=f"cup_{k}")]))
            for _ in range(3):
                executor.spin_once(0.02)
        recorder.destroy_node()
        with pytest.raises(PegasusError, match="exists already"):  # a second recording never overwrites
            RecorderNode(parameter_overrides=[Parameter("path", value=str(tmp_path / "ep"))])
    finally:
        rclpy.shutdown()

    assert sorted(p.name for p in (tmp_path / "ep").iterdir()) == ["ep.mcap", "metadata.yaml"]
    bag = read_bag(tmp_path / "ep")
    assert {topic: (kind, len(items)) for topic, (kind, items) in bag.items()} == {
        "/robot_status": ("std_msgs/msg/String", 1), "/image": ("sensor_msgs/msg/Image", 4),
        "/object_pose": ("geometry_msgs/msg/PoseStamped", 4),
        "/detections": ("vision_msgs/msg/Detection3DArray", 4)}
    assert bag["/robot_status"][1][0][1].data == "before the recorder"
    for topic in ("/image", "/object_pose"):
        stamps = [stamp for stamp, _ in bag[topic][1]]
        headers = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in bag[topic][1]]
        assert np.all(np.diff(stamps) >= 0) and np.all(np.diff(headers) > 0) and stamps[0] >= headers[0]
    assert [int(m.data[0]) for _, m in bag["/image"][1]] == [0, 1, 2, 3]
    assert [m.pose.position.x for _, m in bag["/object_pose"][1]] == pytest.approx([0.0, 0.1, 0.2, 0.3])
    assert [m.detections[0].id for _, m in bag["/detections"][1]] == ["cup_0", "cup_1", "cup_2", "cup_3"]
    with Reader(tmp_path / "ep") as reader:
        qos = {c.topic: c.ext.offered_qos_profiles[0] for c in reader.connections}
    assert qos["/image"].reliability.name == "BEST_EFFORT" and qos["/robot_status"].durability.name == "TRANSIENT_LOCAL"


def test_a_bag_name_is_a_directory_and_an_existing_one_is_refused(tmp_path):
    assert bag_directory(tmp_path / "a.mcap") == tmp_path / "a"
    assert bag_directory(tmp_path / "b") == tmp_path / "b"
    (tmp_path / "c").mkdir()
    with pytest.raises(PegasusError, match="exists already"):
        bag_directory(tmp_path / "c.mcap")

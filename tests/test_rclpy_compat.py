"""The rclpy stand-in: the same node code publishes/subscribes, runs timers, serves and calls services,
reads parameters from overrides, on single- and multi-threaded executors; images and poses convert."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nodes.conversions import image_to_numpy, matrix_to_pose, numpy_to_image, pose_to_matrix
from nodes.ros import REAL_ROS, MultiThreadedExecutor, Node, Parameter, SingleThreadedExecutor, msgs, rclpy

pytestmark = pytest.mark.skipif(REAL_ROS, reason="these test the stand-in; with ROS 2 the real rclpy is used")


class Talker(Node):
    def __init__(self, **kw):
        super().__init__("talker", **kw)
        self.declare_parameter("greeting", "hello")
        self.declare_parameter("period", 0.01)
        self.pub = self.create_publisher(msgs.String, "chatter", 10)
        self.count = 0
        self.timer = self.create_timer(self.get_parameter("period").value, self.tick)
        self.srv = self.create_service(msgs.Trigger, "reset", self.reset)

    def tick(self):
        self.count += 1
        self.pub.publish(msgs.String(data=f"{self.get_parameter('greeting').value} {self.count}"))

    def reset(self, request, response):
        self.count = 0
        response.success, response.message = True, "reset"
        return response


class Listener(Node):
    def __init__(self):
        super().__init__("listener")
        self.heard = []
        self.create_subscription(msgs.String, "chatter", lambda m: self.heard.append(m.data), 10)


@pytest.mark.parametrize("executor_type", [SingleThreadedExecutor, MultiThreadedExecutor])
def test_publisher_subscriber_timer_service_and_parameters(executor_type):
    rclpy.init()
    try:
        talker = Talker(parameter_overrides=[Parameter("greeting", value="hi")])
        listener = Listener()
        executor = executor_type()
        executor.add_node(talker)
        executor.add_node(listener)
        for _ in range(200):
            executor.spin_once(timeout_sec=0.05)
            if len(listener.heard) >= 5:
                break
        assert listener.heard[:3] == ["hi 1", "hi 2", "hi 3"]
        client = listener.create_client(msgs.Trigger, "reset")
        assert client.wait_for_service(timeout_sec=1.0)
        future = client.call_async(msgs.Trigger.Request())
        executor.spin_until_future_complete(future, timeout_sec=2.0)
        assert future.done() and future.result().success and talker.count == 0
        with pytest.raises(Exception):
            talker.get_parameter("undeclared")
        executor.shutdown()
    finally:
        rclpy.shutdown()


def test_keep_last_depth_drops_the_oldest_and_publish_checks_the_type():
    rclpy.init()
    try:
        node = Node("n")
        got = []
        node.create_subscription(msgs.String, "t", lambda m: got.append(m.data), 2)
        pub = node.create_publisher(msgs.String, "t", 10)
        for k in range(5):
            pub.publish(msgs.String(data=str(k)))
        rclpy.spin_once(node, timeout_sec=0.1)
        rclpy.spin_once(node, timeout_sec=0.1)
        assert got == ["3", "4"]
        with pytest.raises(TypeError):
            pub.publish("not a message")
    finally:
        rclpy.shutdown()


def test_image_and_pose_conversions_round_trip():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (4, 6, 3), dtype=np.uint8)
    msg = numpy_to_image(rgb, "rgb8")
    assert (msg.height, msg.width, msg.step) == (4, 6, 18)
    np.testing.assert_array_equal(image_to_numpy(msg), rgb)
    depth = rng.random((4, 6)).astype(np.float32)
    np.testing.assert_array_equal(image_to_numpy(numpy_to_image(depth, "32FC1")), depth)
    with pytest.raises(ValueError):
        numpy_to_image(rgb, "mono8")
    # a driver's image: rows padded to 8 bytes, big-endian 16-bit depth
    mm = rng.integers(0, 5000, (3, 5), dtype=np.uint16)
    padded = np.zeros((3, 16), np.uint8)
    padded[:, :10] = mm.astype(">u2").view(np.uint8).reshape(3, 10)
    msg = msgs.Image(height=3, width=5, encoding="16UC1", is_bigendian=1, step=16, data=padded.tobytes())
    np.testing.assert_array_equal(image_to_numpy(msg), mm)
    msg.step = 8  # shorter than a row
    with pytest.raises(ValueError, match="does not hold"):
        image_to_numpy(msg)
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=1).as_matrix()
    T[:3, 3] = [0.1, -0.2, 0.7]
    np.testing.assert_allclose(pose_to_matrix(matrix_to_pose(T)), T, atol=1e-12)


def test_parameters_are_statically_typed_as_in_rclpy():
    from nodes.compat import (
        InvalidParameterTypeException,
        ParameterNotDeclaredException,
        ParameterUninitializedException,
        ParameterValue,
    )

    T = Parameter.Type
    assert [T.from_parameter_value(v) for v in (None, True, 1, 1.0, "a", [], [1.0], ("a",), [b"x"])] == \
        [T.NOT_SET, T.BOOL, T.INTEGER, T.DOUBLE, T.STRING, T.BYTE_ARRAY, T.DOUBLE_ARRAY, T.STRING_ARRAY, T.BYTE_ARRAY]
    with pytest.raises(ValueError):
        Parameter("rate", T.DOUBLE, 5)  # the type and the value must agree
    with pytest.raises(TypeError):
        Parameter("mixed", value=[1, "a"])
    node = Node("typed", parameter_overrides=[Parameter("rate", value=5), Parameter("scale", value=2.0),
                                              Parameter("axis", value=[])])
    with pytest.raises(InvalidParameterTypeException, match="'rate' to '5' of type 'INTEGER', expecting type 'DOUBLE'"):
        node.declare_parameter("rate", 1.0)  # an int override of a double parameter
    assert node.declare_parameter("scale", 1.0).value == 2.0
    with pytest.raises(InvalidParameterTypeException, match="BYTE_ARRAY"):
        node.declare_parameter("axis", [0.0, 0.0, 1.0])  # an empty list is a byte array
    node.declare_parameter("name", T.STRING)  # by type alone: declared, not initialised
    with pytest.raises(ParameterUninitializedException):
        node.get_parameter("name")
    with pytest.raises(InvalidParameterTypeException):
        node.set_parameters([Parameter("scale", value="big")])
    node.set_parameters([Parameter("name", value="cup"), Parameter("scale", value=3.0)])
    assert node.get_parameter("name").value == "cup" and node.get_parameter("scale").value == 3.0
    assert node.get_parameter("scale").get_parameter_value() == ParameterValue(type=3, double_value=3.0)
    with pytest.raises(ParameterNotDeclaredException):
        node.set_parameters([Parameter("undeclared", value=1)])


def test_camera_info_carries_k_p_r_d_and_the_distortion_model():
    from nodes.conversions import camera_info

    K = np.array([[554.3, 0.0, 319.5], [0.0, 553.9, 241.2], [0.0, 0.0, 1.0]])
    assert list(msgs.CameraInfo().d) == [] and list(msgs.CameraInfo().r) == [0.0] * 9  # ROS 2's defaults: set them
    info = camera_info(K, 640, 480, msgs.Header(frame_id="camera"))
    P = np.array(info.p).reshape(3, 4)
    np.testing.assert_array_equal(P[:, :3], K)
    assert (P[:, 3] == 0).all() and np.array_equal(np.array(info.r).reshape(3, 3), np.eye(3))
    assert info.distortion_model == "plumb_bob" and list(info.d) == [0.0] * 5
    assert (info.width, info.height) == (640, 480)
    # a point in the camera frame projects to the same pixel through K and through P
    X = np.array([0.1, -0.05, 0.8])
    np.testing.assert_allclose((K @ X)[:2] / X[2], (P @ np.append(X, 1.0))[:2] / X[2])
    assert camera_info(K, 640, 480, distortion=[0.1, -0.2, 0.0, 0.0, 0.05]).d.tolist() == [0.1, -0.2, 0.0, 0.0, 0.05]


def test_a_late_subscriber_gets_each_latched_publishers_last_message():
    from nodes.ros import latched

    rclpy.init()
    try:
        a, b, late = Node("a"), Node("b"), Node("late")
        for node, text in ((a, "a1"), (a, "a2"), (b, "b1")):
            pub = next((p for p in node.publishers if p.topic == "/state"), None) or \
                node.create_publisher(msgs.String, "state", latched())
            pub.publish(msgs.String(data=text))
        got = []
        late.create_subscription(msgs.String, "state", lambda m: got.append(m.data), latched(10))
        executor = SingleThreadedExecutor()
        executor.add_node(late)
        executor.spin_once(0.1)
        executor.spin_once(0.1)
        assert sorted(got) == ["a2", "b1"]  # one message per publisher, its last
        a.destroy_node()
        later, got2 = Node("later"), []
        later.create_subscription(msgs.String, "state", lambda m: got2.append(m.data), latched(10))
        executor.add_node(later)
        executor.spin_once(0.1)
        assert got2 == ["b1"]  # a destroyed publisher's message is gone with it
    finally:
        rclpy.shutdown()


def test_qos_and_type_mismatches_pass_nothing_as_in_ros2(caplog):
    """DDS's request-offered rules: a best-effort publisher reaches no reliable subscription, a volatile
    subscription gets no latched history, a subscription of another type gets nothing; each is logged."""
    from nodes.compat import QoSProfile, ReliabilityPolicy
    from nodes.ros import latched

    rclpy.init()
    try:
        node = Node("qos")
        best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
        got = {name: [] for name in ("reliable", "best_effort", "volatile", "latched", "other_type")}
        node.create_subscription(msgs.String, "a", lambda m: got["reliable"].append(m.data), 10)
        node.create_subscription(msgs.String, "a", lambda m: got["best_effort"].append(m.data), best_effort)
        pub = node.create_publisher(msgs.String, "a", best_effort)
        assert "incompatible QoS" in caplog.text and "RELIABILITY" in caplog.text
        assert pub.get_subscription_count() == 1
        pub.publish(msgs.String(data="x"))
        state = node.create_publisher(msgs.String, "state", latched())
        state.publish(msgs.String(data="s"))
        node.create_subscription(msgs.String, "state", lambda m: got["volatile"].append(m.data), 10)
        node.create_subscription(msgs.String, "state", lambda m: got["latched"].append(m.data), latched())
        node.create_subscription(msgs.Header, "state", lambda m: got["other_type"].append(m), latched())
        assert "type String" in caplog.text
        for _ in range(4):
            rclpy.spin_once(node, timeout_sec=0.05)
        assert got == {"reliable": [], "best_effort": ["x"], "volatile": [], "latched": ["s"], "other_type": []}
        assert dict(node.get_topic_names_and_types()) == {
            "/a": ["std_msgs/msg/String"], "/state": ["std_msgs/msg/Header", "std_msgs/msg/String"]}
    finally:
        rclpy.shutdown()


def test_topic_names_expand_and_break_as_in_ros2():
    from nodes.compat import InvalidTopicNameException

    rclpy.init()
    try:
        node = Node("cam", namespace="/left")
        assert node.resolve_topic_name("image") == "/left/image"
        assert node.resolve_topic_name("/tf") == "/tf"
        assert node.resolve_topic_name("~/info") == "/left/cam/info"
        for bad in ("2image", "image/", "a__b", "with space", "a//b"):
            with pytest.raises(InvalidTopicNameException):
                node.create_publisher(msgs.String, bad, 1)
    finally:
        rclpy.shutdown()

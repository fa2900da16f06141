"""The rclpy stand-in against real rclpy: the same node code publishes/subscribes, runs timers, serves and
calls services, reads parameters from overrides, on single- and multi-threaded executors; parameters, QoS,
latching and topic names behave alike. Each test that states rclpy's behaviour runs on both implementations
(``ros`` fixture: the stand-in, and real rclpy over Fast DDS where the ros extra is installed), so that a
difference fails; images and poses convert."""

import numpy as np
import pytest
from conftest import spin_until
from scipy.spatial.transform import Rotation

from nodes.conversions import image_to_numpy, matrix_to_pose_msg, numpy_to_image, pose_msg_to_matrix
from nodes.ros import msgs


def talker_and_listener(ros, **kw):
    String = ros.message("std_msgs/msg/String")

    class Talker(ros.Node):
        def __init__(self):
            super().__init__("talker", **kw)
            self.declare_parameter("greeting", "hello")
            self.declare_parameter("period", 0.01)
            self.pub = self.create_publisher(String, "chatter", 10)
            self.count = 0
            self.timer = self.create_timer(self.get_parameter("period").value, self.tick)
            self.srv = self.create_service(ros.Trigger, "reset", self.reset)

        def tick(self):
            self.count += 1
            self.pub.publish(String(data=f"{self.get_parameter('greeting').value} {self.count}"))

        def reset(self, request, response):
            self.count_at_reset, self.count = self.count, 0
            response.success, response.message = True, "reset"
            return response

    class Listener(ros.Node):
        def __init__(self):
            super().__init__("listener")
            self.heard = []
            self.create_subscription(String, "chatter", lambda m: self.heard.append(m.data), 10)

    return Talker(), Listener()


@pytest.mark.parametrize("executor_name", ["SingleThreadedExecutor", "MultiThreadedExecutor"])
def test_publisher_subscriber_timer_service_and_parameters(ros, executor_name):
    ros.init()
    try:
        talker, listener = talker_and_listener(ros, parameter_overrides=[ros.Parameter("greeting", value="hi")])
        executor = getattr(ros, executor_name)()
        executor.add_node(talker)
        executor.add_node(listener)
        assert spin_until(executor, lambda: len(listener.heard) >= 5)
        # the first messages may go out before DDS has matched the two (the stand-in's graph matches at once)
        first = int(listener.heard[0].split()[1])
        assert listener.heard[:3] == [f"hi {first}", f"hi {first + 1}", f"hi {first + 2}"]
        assert ros.real or first == 1
        client = listener.create_client(ros.Trigger, "reset")
        assert client.wait_for_service(timeout_sec=5.0)
        future = client.call_async(ros.Trigger.Request())
        executor.spin_until_future_complete(future, timeout_sec=5.0)
        assert future.done() and future.result().success and future.result().message == "reset"
        assert talker.count_at_reset >= 5  # served by the talker, its timer still running
        with pytest.raises(ros.exceptions.ParameterNotDeclaredException):
            talker.get_parameter("undeclared")
        executor.shutdown()
    finally:
        ros.rclpy.shutdown()


def test_keep_last_depth_drops_the_oldest_and_publish_checks_the_type(ros):
    String = ros.message("std_msgs/msg/String")
    ros.init()
    try:
        node = ros.Node("n")
        got = []
        node.create_subscription(String, "t", lambda m: got.append(m.data), 2)
        pub = node.create_publisher(String, "t", 10)
        executor = ros.SingleThreadedExecutor()
        executor.add_node(node)
        assert spin_until(executor, lambda: pub.get_subscription_count() == 1)
        for k in range(5):
            pub.publish(String(data=str(k)))
        if ros.real:  # let DDS deliver all five into the reader's history of two before the callbacks run
            pub.wait_for_all_acked()
        spin_until(executor, lambda: len(got) >= 2, settle=ros.settle)
        assert got == ["3", "4"]
        with pytest.raises(TypeError):
            pub.publish("not a message")
    finally:
        ros.rclpy.shutdown()


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
    np.testing.assert_allclose(pose_msg_to_matrix(matrix_to_pose_msg(T)), T, atol=1e-12)


def test_parameters_are_statically_typed_as_in_rclpy(ros):
    import array

    ex, Parameter = ros.exceptions, ros.Parameter
    T = Parameter.Type
    values = (None, True, 1, 1.0, "a", [], (), [1.0], ("a",), [b"x"], [True, 1], array.array("d", [1.0]),
              np.float64(1.0))
    assert [T.from_parameter_value(v) for v in values] == \
        [T.NOT_SET, T.BOOL, T.INTEGER, T.DOUBLE, T.STRING, T.BYTE_ARRAY, T.BYTE_ARRAY, T.DOUBLE_ARRAY, T.STRING_ARRAY,
         T.BYTE_ARRAY, T.INTEGER_ARRAY, T.DOUBLE_ARRAY, T.DOUBLE]
    for value in (np.int64(3), [1, "a"], {"a": 1}):  # a numpy integer is no int; one element type per array
        with pytest.raises(TypeError):
            T.from_parameter_value(value)
    with pytest.raises(ValueError):
        Parameter("rate", T.DOUBLE, 5)  # the type and the value must agree
    with pytest.raises(ValueError):
        Parameter("axis", T.DOUBLE_ARRAY, [1, 2])
    assert Parameter("flag", T.INTEGER, True).type_ == T.INTEGER  # a bool is an int here, as in Python
    with pytest.raises(TypeError):
        Parameter("mixed", value=[1, "a"])
    ros.init()
    try:
        node = ros.Node("typed", parameter_overrides=[Parameter("rate", value=5), Parameter("scale", value=2.0),
                                                      Parameter("axis", value=[])])
        with pytest.raises(ex.InvalidParameterTypeException,
                           match="^Trying to set parameter 'rate' to '5' of type 'INTEGER', expecting type 'DOUBLE': "
                                 "rate$"):
            node.declare_parameter("rate", 1.0)  # an int override of a double parameter
        assert node.declare_parameter("scale", 1.0).value == 2.0
        with pytest.raises(ex.ParameterAlreadyDeclaredException):
            node.declare_parameter("scale", 1.0)
        with pytest.raises(ex.InvalidParameterTypeException, match="BYTE_ARRAY"):
            node.declare_parameter("axis", [0.0, 0.0, 1.0])  # an empty list is a byte array
        with pytest.raises(ValueError, match="NOT_SET"):
            node.declare_parameter("nothing", T.NOT_SET)
        with pytest.warns(UserWarning, match="only providing its name is deprecated"):
            assert node.declare_parameter("anything").type_ == T.NOT_SET  # dynamically typed
        node.declare_parameter("name", T.STRING)  # by type alone: declared, not initialised
        with pytest.raises(ex.ParameterUninitializedException, match="The parameter 'name' is not initialized"):
            node.get_parameter("name")
        node.declare_parameter("fixed", 1, ros.ParameterDescriptor(read_only=True))
        # set_parameters refuses another type or a read-only parameter in its results, without raising
        results = node.set_parameters([Parameter("scale", value="big"), Parameter("fixed", value=2)])
        assert [(r.successful, r.reason) for r in results] == [
            (False, "Wrong parameter type, expected 'Type.DOUBLE' got 'Type.STRING'"),
            (False, "Trying to set a read-only parameter: fixed.")]
        assert node.get_parameter("scale").value == 2.0 and node.get_parameter("fixed").value == 1
        results = node.set_parameters([Parameter("name", value="cup"), Parameter("scale", value=3.0)])
        assert [r.successful for r in results] == [True, True]
        assert node.get_parameter("name").value == "cup" and node.get_parameter("scale").value == 3.0
        assert node.get_parameter("scale").get_parameter_value() == ros.ParameterValue(type=3, double_value=3.0)
        with pytest.raises(ex.ParameterNotDeclaredException):
            node.set_parameters([Parameter("undeclared", value=1)])
        with pytest.raises(ex.ParameterNotDeclaredException):
            node.get_parameter("undeclared")
        assert issubclass(ex.ParameterNotDeclaredException, ex.ParameterException)
        assert issubclass(ex.InvalidParameterTypeException, ex.ParameterException)
    finally:
        ros.rclpy.shutdown()


def test_timers_take_a_zero_period_and_refuse_a_negative_one(ros):
    ros.init()
    try:
        node = ros.Node("timers")
        calls = []
        node.create_timer(0.0, lambda: calls.append(1))  # due at every spin
        with pytest.raises(ros.RCLError, match="non-negative"):
            node.create_timer(-1.0, lambda: None)
        executor = ros.SingleThreadedExecutor()
        executor.add_node(node)
        assert spin_until(executor, lambda: len(calls) >= 3, timeout=2.0)
    finally:
        ros.rclpy.shutdown()


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


def test_a_late_subscriber_gets_each_latched_publishers_last_message(ros):
    String = ros.message("std_msgs/msg/String")
    latched = lambda depth=1: ros.QoSProfile(depth=depth, durability=ros.DurabilityPolicy.TRANSIENT_LOCAL)  # noqa: E731
    ros.init()
    try:
        a, b, late = ros.Node("a"), ros.Node("b"), ros.Node("late")
        for node, text in ((a, "a1"), (a, "a2"), (b, "b1")):
            pub = next((p for p in node.publishers if p.topic == "state" and p.topic_name == "/state"), None) or \
                node.create_publisher(String, "state", latched())
            pub.publish(String(data=text))
        got = []
        late.create_subscription(String, "state", lambda m: got.append(m.data), latched(10))
        executor = ros.SingleThreadedExecutor()
        executor.add_node(late)
        spin_until(executor, lambda: len(got) >= 2, settle=ros.settle)
        assert sorted(got) == ["a2", "b1"]  # one message per publisher, its last
        a.destroy_node()
        later, got2 = ros.Node("later"), []
        later.create_subscription(String, "state", lambda m: got2.append(m.data), latched(10))
        executor.add_node(later)
        spin_until(executor, lambda: len(got2) >= 1, settle=ros.settle)
        assert got2 == ["b1"]  # a destroyed publisher's message is gone with it
    finally:
        ros.rclpy.shutdown()


def test_qos_and_type_mismatches_pass_nothing_as_in_ros2(ros, caplog, capfd):
    """DDS's request-offered rules: a best-effort publisher reaches no reliable subscription, a volatile
    subscription gets no latched history, a subscription of another type (in another context: another
    process) gets nothing; each is logged on both sides. In one context a second type on a topic is refused."""
    String, Header = ros.message("std_msgs/msg/String"), ros.message("std_msgs/msg/Header")
    latched = lambda: ros.QoSProfile(depth=1, durability=ros.DurabilityPolicy.TRANSIENT_LOCAL)  # noqa: E731
    ros.init()
    other = ros.other_context()
    ros.init(context=other)
    try:
        node = ros.Node("qos")
        best_effort = ros.QoSProfile(depth=10, reliability=ros.ReliabilityPolicy.BEST_EFFORT)
        got = {name: [] for name in ("reliable", "best_effort", "volatile", "latched", "other_type")}
        node.create_subscription(String, "a", lambda m: got["reliable"].append(m.data), 10)
        node.create_subscription(String, "a", lambda m: got["best_effort"].append(m.data), best_effort)
        pub = node.create_publisher(String, "a", best_effort)
        state = node.create_publisher(String, "state", latched())
        state.publish(String(data="s"))
        node.create_subscription(String, "state", lambda m: got["volatile"].append(m.data), 10)
        node.create_subscription(String, "state", lambda m: got["latched"].append(m.data), latched())
        with pytest.raises(ros.RCLError, match="incompatible type"):
            node.create_publisher(Header, "state", 1)
        with pytest.raises(ros.RCLError):  # (rcl's message for it is "invalid allocator")
            node.create_subscription(Header, "state", lambda m: None, latched())
        elsewhere = ros.Node("elsewhere", context=other)
        elsewhere.create_subscription(Header, "state", lambda m: got["other_type"].append(m), latched())
        executor, executor2 = ros.SingleThreadedExecutor(), ros.SingleThreadedExecutor(context=other)
        executor.add_node(node)
        executor2.add_node(elsewhere)
        assert spin_until(executor, lambda: pub.get_subscription_count() == 1)
        pub.publish(String(data="x"))
        spin_until(executor, lambda: got["best_effort"] and got["latched"], settle=ros.settle)
        spin_until(executor2, lambda: False, timeout=ros.settle)
        assert got == {"reliable": [], "best_effort": ["x"], "volatile": [], "latched": ["s"], "other_type": []}
        log = caplog.text + capfd.readouterr().err
        for side in ("New publisher discovered on topic 'a', offering incompatible QoS. No messages will be "
                     "received from it. Last incompatible policy: RELIABILITY",
                     "New subscription discovered on topic 'a', requesting incompatible QoS. No messages will be "
                     "sent to it. Last incompatible policy: RELIABILITY"):
            assert side in log
        if not ros.real:  # Fast DDS (rmw_fastrtps_cpp) raises no incompatible-type event: nothing is logged
            assert "Incompatible type on topic 'state', no messages will be sent to it." in log
        names = {name: sorted(types) for name, types in node.get_topic_names_and_types()}
        assert {name: names[name] for name in ("/a", "/state")} == {
            "/a": ["std_msgs/msg/String"], "/state": ["std_msgs/msg/Header", "std_msgs/msg/String"]}
        assert [(info.node_name, info.topic_type, info.qos_profile.durability)
                for info in node.get_publishers_info_by_topic("state")] == [
            ("qos", "std_msgs/msg/String", ros.DurabilityPolicy.TRANSIENT_LOCAL)]
    finally:
        ros.rclpy.shutdown(context=other)
        ros.rclpy.shutdown()


@pytest.mark.parametrize("name, expanded", [
    ("image", "/left/image"), ("/tf", "/tf"), ("~/info", "/left/cam/info"), ("~", "/left/cam"),
    ("a__b", "/left/a__b"), ("_x/y_1", "/left/_x/y_1"), ("{node}/x", "/left/cam/x"),
    ("2image", None), ("image/", None), ("with space", None), ("a//b", None), ("/", None), ("a/2b", None),
    ("~info", None), ("a~", None), ("caf\u00e9", None), ("", None),
])
def test_topic_names_expand_and_break_as_in_ros2(ros, name, expanded):
    String = ros.message("std_msgs/msg/String")
    ros.init()
    try:
        node = ros.Node("cam", namespace="/left")
        if expanded is None:
            with pytest.raises(ros.exceptions.InvalidTopicNameException):
                node.create_publisher(String, name, 1)
        else:
            assert node.resolve_topic_name(name) == expanded
            assert node.create_publisher(String, name, 1).topic_name == expanded
        with pytest.raises(ValueError, match="unknown substitution"):
            node.create_publisher(String, "{nope}/x", 1)
    finally:
        ros.rclpy.shutdown()

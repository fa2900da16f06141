"""The stand-in message classes: generated from the ROS 2 Humble definitions, as strict on assignment as
rosidl's generated classes, and serialised to the same CDR bytes a ROS 2 node would put on the wire. The tests
that state rosidl's behaviour run on the stand-in and on the real classes (``ros`` fixture; the real ones from
the ros extra, ROS 2 Jazzy, with their field checks on as nodes.ros sets them), so that a difference fails."""

import array
import importlib.util

import numpy as np
import pytest
from conftest import ros_implementation
from rosbags.typesys import Stores, get_typestore

from nodes import msgs
from nodes.conversions import camera_info, image_to_numpy, matrix_to_pose_msg, numpy_to_image
from nodes.ros import REAL_ROS

HUMBLE = get_typestore(Stores.ROS2_HUMBLE)
# the types the nodes use: ROS 2's wheels, and the packages nodes.ros_interfaces builds (tf2_msgs, vision_msgs)
REAL_TYPES = ["tf2_msgs/msg/TFMessage", "vision_msgs/msg/Detection3DArray", "vision_msgs/msg/Detection3D",
              "vision_msgs/msg/ObjectHypothesisWithPose", "vision_msgs/msg/BoundingBox3D",
              "std_msgs/msg/Header", "std_msgs/msg/String", "sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo",
               "sensor_msgs/msg/RegionOfInterest", "geometry_msgs/msg/Pose", "geometry_msgs/msg/PoseStamped",
               "geometry_msgs/msg/TransformStamped", "geometry_msgs/msg/PoseWithCovariance",
               "std_srvs/srv/Trigger_Response", "std_msgs/msg/Float32", "std_msgs/msg/Byte"]


@pytest.mark.parametrize("type_name", ["sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo",
                                       "geometry_msgs/msg/PoseStamped", "tf2_msgs/msg/TFMessage"])
def test_the_fields_are_the_ros2_definitions(type_name):
    """Field names and order come from the Humble definitions (an independent typestore here)."""
    cls = msgs.message_class(type_name)
    assert [name for name, _ in HUMBLE.fielddefs[type_name][1]] == [slot[1:] for slot in cls.__slots__]
    assert msgs.type_name(cls) == type_name


def real_message(type_name: str):
    """The real class of ``type_name`` (skipped without the ros extra, or without nodes.ros_interfaces' build)."""
    real = ros_implementation("rclpy")
    pytest.importorskip(type_name.split("/")[0], reason="built by python -m nodes.ros_interfaces (make's set-up)")
    return real.message(type_name)


@pytest.mark.parametrize("type_name", REAL_TYPES)
def test_the_fields_and_their_types_are_those_of_the_real_classes(type_name):
    """Field names, order and types (as rosidl spells them) against Jazzy's classes: Humble's definitions,
    which the stand-in is generated from, hold the same for every type the nodes use."""
    assert msgs.message_class(type_name).get_fields_and_field_types() == \
        real_message(type_name).get_fields_and_field_types()


@pytest.mark.parametrize("type_name, field, value", [
    ("geometry_msgs/msg/Point", "x", 1),                             # an int is no float64
    ("sensor_msgs/msg/Image", "height", -1),                         # uint32 below range
    ("sensor_msgs/msg/Image", "height", 2 ** 32),                    # uint32 above range
    ("sensor_msgs/msg/Image", "height", np.int64(5)),                # a numpy integer is no int
    ("sensor_msgs/msg/Image", "height", 480.0),                      # a float is no uint32
    ("sensor_msgs/msg/Image", "encoding", b"rgb8"),                  # bytes are no string
    ("sensor_msgs/msg/CameraInfo", "k", [1.0] * 8),                  # float64[9] needs 9
    ("sensor_msgs/msg/CameraInfo", "k", [1] * 9),                    # ... floats
    ("sensor_msgs/msg/CameraInfo", "k", np.zeros(9, dtype=np.float32)),  # ... of float64
    ("sensor_msgs/msg/CameraInfo", "k", np.zeros(8)),                # ... 9 of them
    ("sensor_msgs/msg/CameraInfo", "d", np.zeros(5)),                # a numpy array is no float64[] sequence
    ("sensor_msgs/msg/CameraInfo", "d", [1, 2]),                     # ints are no float64 items
    ("sensor_msgs/msg/Image", "data", array.array("b", [1, 2])),     # int8 typecode for uint8[]
    ("sensor_msgs/msg/Image", "data", [1, 256]),                     # byte out of range
    ("sensor_msgs/msg/Image", "data", np.zeros(4, np.uint8)),        # a numpy array is no uint8[] either
    ("sensor_msgs/msg/Image", "data", "text"),                       # nor a string
    ("geometry_msgs/msg/PoseStamped", "pose", "Image"),              # nested message of another type
    ("std_msgs/msg/Header", "frame_id", None),
    ("std_msgs/msg/Float32", "data", 1e39),                          # beyond float32's range
    ("std_msgs/msg/String", "data", 5),
    ("std_msgs/msg/Byte", "data", 1),                               # a byte is one bytes object
    ("std_msgs/msg/Byte", "data", b"ab"),
])
def test_a_field_refuses_a_value_of_another_type(ros, type_name, field, value):
    msg = ros.message(type_name)()
    if isinstance(value, str) and value == "Image":
        value = ros.message("sensor_msgs/msg/Image")()
    with pytest.raises(AssertionError):
        setattr(msg, field, value)


def test_a_field_takes_what_rosidl_takes_and_keeps_the_definitions_defaults(ros):
    info = ros.message("sensor_msgs/msg/CameraInfo")()
    assert info.k.dtype == np.float64 and info.k.shape == (9,) and isinstance(info.d, array.array)
    assert list(info.d) == [] and list(info.r) == [0.0] * 9 and info.distortion_model == ""
    info.k = [1.0, 0.0, 2.0, 0.0, 1.0, 3.0, 0.0, 0.0, 1.0]
    assert isinstance(info.k, np.ndarray) and info.k[2] == 2.0
    info.k = np.eye(3).ravel()
    info.d = [0.1, 0.2, 0.0, 0.0, 0.0]
    assert isinstance(info.d, array.array) and info.d.typecode == "d"
    info.d = (0.1,)
    pose = ros.message("geometry_msgs/msg/Pose")()
    pose.position.x = np.float64(0.5)  # a numpy float64 is a float, as rosidl sees it
    pose.position.y = float("nan")  # and a float64 takes any float
    assert pose.orientation.w == 1.0 and pose.orientation.x == 0.0  # Quaternion's default is the identity
    image = ros.message("sensor_msgs/msg/Image")()
    assert isinstance(image.data, array.array) and image.data.typecode == "B"
    for data in (b"\x00\x01", bytearray(b"\x00\x01"), array.array("B", [0, 255]), [0, 255]):
        image.data = data
    image.height = True  # a bool is an int, as in Python
    assert ros.message("std_msgs/msg/Byte")().data == b"\x00"
    ros.message("std_msgs/msg/Byte")().data = b"\xff"
    number = ros.message("std_msgs/msg/Float32")()
    number.data, number.data = 3.0e38, float("inf")
    with pytest.raises(AssertionError, match="Invalid arguments passed to constructor: frame"):
        ros.message("std_msgs/msg/Header")(frame="camera")
    with pytest.raises(AssertionError):
        ros.message("geometry_msgs/msg/Point")(x=1)  # the constructor checks what it sets
    header = ros.message("std_msgs/msg/Header")(frame_id="camera", check_fields=True)
    assert header == ros.message("std_msgs/msg/Header")(frame_id="camera") and header.stamp.sec == 0


def same_messages(ros) -> dict:
    """{type name: message}: the same messages built with ``ros``'s classes, for the CDR comparison (a
    padding byte after a uint8 and after a bool, strings of each length mod 4, sequences and fixed arrays)."""
    M = ros.message
    header = M("std_msgs/msg/Header")(frame_id="camera")
    header.stamp.sec, header.stamp.nanosec = 1700000000, 250
    depth = np.array([0.5, 1.25, 0.0, 3.0], "<f4").tobytes()
    info = M("sensor_msgs/msg/CameraInfo")(header=header, height=480, width=640, distortion_model="rational_polynomial",
                                           d=[0.1, -0.2, 0.0, 0.001, 0.05, 0.0, 0.0, 0.0],
                                           k=[500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0], binning_x=2)
    info.roi.do_rectify, info.roi.width = True, 7
    pose = M("geometry_msgs/msg/PoseStamped")(header=header)
    pose.pose.position.x, pose.pose.orientation.z, pose.pose.orientation.w = 0.25, 0.6, 0.8
    transform = M("geometry_msgs/msg/TransformStamped")(header=header, child_frame_id="cup_0")
    transform.transform.translation.z = -0.125
    built = {}
    if not ros.real or importlib.util.find_spec("vision_msgs"):
        hypothesis = M("vision_msgs/msg/ObjectHypothesisWithPose")()
        hypothesis.hypothesis.class_id, hypothesis.hypothesis.score = "noodle_cup_red", 0.75
        hypothesis.pose.pose = pose.pose
        built["vision_msgs/msg/Detection3DArray"] = M("vision_msgs/msg/Detection3DArray")(
            header=header, detections=[M("vision_msgs/msg/Detection3D")(header=header, results=[hypothesis], id="c")])
    if not ros.real or importlib.util.find_spec("tf2_msgs"):
        built["tf2_msgs/msg/TFMessage"] = M("tf2_msgs/msg/TFMessage")(transforms=[transform, transform])
    return built | {
        "sensor_msgs/msg/Image": M("sensor_msgs/msg/Image")(header=header, height=2, width=2, encoding="32FC1",
                                                           is_bigendian=0, step=8, data=depth),
        "sensor_msgs/msg/CameraInfo": info,
        "geometry_msgs/msg/PoseStamped": pose,
        "geometry_msgs/msg/TransformStamped": transform,
        "std_srvs/srv/Trigger_Response": ros.Trigger.Response(success=True, message="reset"),
        "std_msgs/msg/String": M("std_msgs/msg/String")(data="abc"),
        "std_msgs/msg/Byte": M("std_msgs/msg/Byte")(data=b"\x7f"),  # a fixed-size type
        "rcl_interfaces/msg/ParameterEvent": M("rcl_interfaces/msg/ParameterEvent")(
            node="/camera_node", new_parameters=[M("rcl_interfaces/msg/Parameter")(
                name="source", value=M("rcl_interfaces/msg/ParameterValue")(
                    type=4, string_value="sim", bool_array_value=[True, False], integer_value=-3))]),
    }


def test_cdr_bytes_are_those_of_rclpy_serialize_message():
    """The stand-in's CDR against ``rclpy.serialization.serialize_message`` of the same message: the same bytes
    except padding, which no reader reads: between fields Fast CDR leaves it unset (whatever the buffer held;
    the stand-in writes zeros), and its message may end in up to 8 bytes past the data (a fixed-size type's
    to a multiple of 4; rosbags' reader refuses more than 3). Each side's bytes read back as the other's
    message."""
    real = ros_implementation("rclpy")
    standin, reference = same_messages(ros_implementation("stand-in")), same_messages(real)
    for type_name, msg in standin.items():
        if type_name not in reference:
            continue  # tf2_msgs, vision_msgs: not built here (python -m nodes.ros_interfaces)
        ours, theirs = msgs.serialize(msg), real.serialize(reference[type_name])
        assert ours[:4] == theirs[:4] == b"\x00\x01\x00\x00", type_name  # CDR, little endian
        assert len(ours) <= len(theirs) <= len(ours) + 8, type_name
        theirs = theirs[:len(ours)]
        assert msgs.deserialize(theirs, type_name) == msg, type_name
        assert msgs.serialize(msgs.deserialize(theirs, type_name)) == ours, type_name
        assert real.deserialize(ours, type_name) == reference[type_name], type_name
        padding = [i for i in range(len(ours)) if ours[i] != theirs[i]]
        assert all(ours[i] == 0 for i in padding), type_name


@pytest.mark.skipif(REAL_ROS, reason="nodes.conversions makes ROS 2's own messages where ROS 2 is installed")
def test_cdr_bytes_round_trip_and_match_an_independent_serialisation():
    """What the stand-in serialises reads back equal, and is byte for byte what rosbags' own typestore writes
    for the same message built by hand (so `ros2 bag` and Foxglove read it)."""
    header = msgs.Header(frame_id="camera")
    header.stamp.sec, header.stamp.nanosec = 1700000000, 250
    depth = numpy_to_image(np.array([[0.5, 1.25], [0.0, 3.0]], dtype=np.float32), "32FC1", header)
    assert msgs.deserialize(msgs.serialize(depth), "sensor_msgs/msg/Image") == depth
    np.testing.assert_array_equal(image_to_numpy(msgs.deserialize(msgs.serialize(depth), depth.TYPE_NAME)),
                                  image_to_numpy(depth))
    T = HUMBLE.types
    stamp = T["builtin_interfaces/msg/Time"](sec=1700000000, nanosec=250)
    reference = T["sensor_msgs/msg/Image"](
        header=T["std_msgs/msg/Header"](stamp=stamp, frame_id="camera"), height=2, width=2, encoding="32FC1",
        is_bigendian=0, step=8, data=np.frombuffer(np.array([0.5, 1.25, 0.0, 3.0], "<f4").tobytes(), np.uint8))
    assert msgs.serialize(depth) == bytes(HUMBLE.serialize_cdr(reference, "sensor_msgs/msg/Image"))

    info = camera_info(np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), 640, 480, header)
    back = HUMBLE.deserialize_cdr(msgs.serialize(info), "sensor_msgs/msg/CameraInfo")
    np.testing.assert_array_equal(back.p.reshape(3, 4)[:, :3], np.array(info.k).reshape(3, 3))
    assert back.distortion_model == "plumb_bob" and back.header.frame_id == "camera"

    stamped = msgs.PoseStamped(header=header, pose=matrix_to_pose_msg(np.eye(4)))
    assert msgs.deserialize(msgs.serialize(stamped), stamped.TYPE_NAME) == stamped
    detections = msgs.Detection3DArray(header=header, detections=[msgs.Detection3D(id="cup_0")])
    assert msgs.deserialize(msgs.serialize(detections), detections.TYPE_NAME).detections[0].id == "cup_0"

"""The stand-in message classes: generated from the ROS 2 Humble definitions, as strict on assignment as
rosidl's generated classes, and serialised to the same CDR bytes a ROS 2 node would put on the wire."""

import array

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from nodes import msgs
from nodes.conversions import camera_info, image_to_numpy, matrix_to_pose, numpy_to_image
from nodes.ros import REAL_ROS

pytestmark = pytest.mark.skipif(REAL_ROS, reason="these test the stand-in messages; with ROS 2 rosidl's are used")

HUMBLE = get_typestore(Stores.ROS2_HUMBLE)


@pytest.mark.parametrize("type_name", ["sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo",
                                       "geometry_msgs/msg/PoseStamped", "tf2_msgs/msg/TFMessage"])
def test_the_fields_are_the_ros2_definitions(type_name):
    """Field names and order come from the Humble definitions (an independent typestore here)."""
    cls = msgs.message_class(type_name)
    assert [name for name, _ in HUMBLE.fielddefs[type_name][1]] == [slot[1:] for slot in cls.__slots__]
    assert msgs.type_name(cls) == type_name


@pytest.mark.parametrize("make, field, value", [
    (msgs.message_class("geometry_msgs/msg/Point"), "x", 1),  # an int is no float64
    (msgs.Image, "height", -1),                                # uint32 below range
    (msgs.Image, "height", 2 ** 32),                           # uint32 above range
    (msgs.Image, "height", np.int64(5)),                       # a numpy integer is no int
    (msgs.Image, "height", 480.0),                             # a float is no uint32
    (msgs.Image, "encoding", b"rgb8"),                         # bytes are no string
    (msgs.CameraInfo, "k", [1.0] * 8),                         # float64[9] needs 9
    (msgs.CameraInfo, "k", [1] * 9),                           # ... floats
    (msgs.CameraInfo, "k", np.zeros(9, dtype=np.float32)),     # ... of float64
    (msgs.CameraInfo, "d", np.zeros(5)),                       # a numpy array is no float64[] sequence
    (msgs.Image, "data", array.array("b", [1, 2])),            # int8 typecode for uint8[]
    (msgs.Image, "data", [1, 256]),                            # byte out of range
    (msgs.PoseStamped, "pose", msgs.Image()),                  # nested message of another type
    (msgs.Header, "frame_id", None),
])
def test_a_field_refuses_a_value_of_another_type(make, field, value):
    msg = make()
    with pytest.raises(AssertionError):
        setattr(msg, field, value)


def test_a_field_takes_what_rosidl_takes_and_keeps_the_definitions_defaults():
    info = msgs.CameraInfo()
    assert info.k.dtype == np.float64 and info.k.shape == (9,) and isinstance(info.d, array.array)
    info.k = [1.0, 0.0, 2.0, 0.0, 1.0, 3.0, 0.0, 0.0, 1.0]
    info.k = np.eye(3).ravel()
    info.d = [0.1, 0.2, 0.0, 0.0, 0.0]
    pose = msgs.Pose()
    pose.position.x = np.float64(0.5)  # a numpy float64 is a float, as rosidl sees it
    assert pose.orientation.w == 1.0 and pose.orientation.x == 0.0  # Quaternion's default is the identity
    image = msgs.Image()
    image.data = b"\x00\x01"
    image.data = array.array("B", [0, 255])
    with pytest.raises(AssertionError, match="Invalid arguments"):
        msgs.Header(frame="camera")


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

    stamped = msgs.PoseStamped(header=header, pose=matrix_to_pose(np.eye(4)))
    assert msgs.deserialize(msgs.serialize(stamped), stamped.TYPE_NAME) == stamped
    detections = msgs.Detection3DArray(header=header, detections=[msgs.Detection3D(id="cup_0")])
    assert msgs.deserialize(msgs.serialize(detections), detections.TYPE_NAME).detections[0].id == "cup_0"

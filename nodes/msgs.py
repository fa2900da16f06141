"""Message types for the stand-in layer, field for field as their ROS 2 definitions (std_msgs, sensor_msgs,
geometry_msgs, vision_msgs, builtin_interfaces, std_srvs), with numpy payloads, and conversions:
images <-> numpy arrays, poses <-> 4x4 matrices. ``nodes.ros`` exports the real ROS 2 types instead
when rclpy is installed; the conversion functions work on either.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation


@dataclass
class TimeMsg:  # builtin_interfaces/Time
    sec: int = 0
    nanosec: int = 0


@dataclass
class Header:  # std_msgs/Header
    stamp: TimeMsg = field(default_factory=TimeMsg)
    frame_id: str = ""


@dataclass
class String:  # std_msgs/String
    data: str = ""


@dataclass
class Image:  # sensor_msgs/Image; data: bytes (as ROS) or a numpy array
    header: Header = field(default_factory=Header)
    height: int = 0
    width: int = 0
    encoding: str = ""
    is_bigendian: int = 0
    step: int = 0
    data: object = b""


@dataclass
class CameraInfo:  # sensor_msgs/CameraInfo
    header: Header = field(default_factory=Header)
    height: int = 0
    width: int = 0
    distortion_model: str = "plumb_bob"
    d: list = field(default_factory=lambda: [0.0] * 5)
    k: list = field(default_factory=lambda: [0.0] * 9)
    r: list = field(default_factory=lambda: [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0])
    p: list = field(default_factory=lambda: [0.0] * 12)


@dataclass
class Point:
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass
class Vector3:
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass
class Quaternion:
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    w: float = 1.0


@dataclass
class Pose:  # geometry_msgs/Pose
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseStamped:
    header: Header = field(default_factory=Header)
    pose: Pose = field(default_factory=Pose)


@dataclass
class Transform:
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped:
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
class ObjectHypothesis:  # vision_msgs/ObjectHypothesis
    class_id: str = ""
    score: float = 0.0


@dataclass
class PoseWithCovariance:
    pose: Pose = field(default_factory=Pose)
    covariance: list = field(default_factory=lambda: [0.0] * 36)


@dataclass
class ObjectHypothesisWithPose:
    hypothesis: ObjectHypothesis = field(default_factory=ObjectHypothesis)
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)


@dataclass
class BoundingBox3D:
    center: Pose = field(default_factory=Pose)
    size: Vector3 = field(default_factory=Vector3)


@dataclass
class Detection3D:
    header: Header = field(default_factory=Header)
    results: list = field(default_factory=list)  # [ObjectHypothesisWithPose]
    bbox: BoundingBox3D = field(default_factory=BoundingBox3D)
    id: str = ""


@dataclass
class Detection3DArray:
    header: Header = field(default_factory=Header)
    detections: list = field(default_factory=list)  # [Detection3D]


class Trigger:  # std_srvs/Trigger
    @dataclass
    class Request:
        pass

    @dataclass
    class Response:
        success: bool = False
        message: str = ""


# -- conversions ------------------------------------------------------------------------------------------
ENCODINGS = {"rgb8": (np.uint8, 3), "bgr8": (np.uint8, 3), "mono8": (np.uint8, 1), "mono16": (np.uint16, 1),
             "16UC1": (np.uint16, 1), "32FC1": (np.float32, 1)}


def numpy_to_image(array: np.ndarray, encoding: str, msg_type=Image, header=None):
    """An Image message (of ``msg_type``: ours or sensor_msgs.msg.Image) holding ``array`` [H, W(, C)]."""
    dtype, channels = ENCODINGS[encoding]
    array = np.ascontiguousarray(array, dtype=dtype)
    if array.ndim != (2 if channels == 1 else 3) or (channels > 1 and array.shape[2] != channels):
        raise ValueError(f"an image of shape {array.shape} is not {encoding}")
    msg = msg_type()
    if header is not None:
        msg.header = header
    msg.height, msg.width, msg.encoding = array.shape[0], array.shape[1], encoding
    msg.is_bigendian, msg.step = 0, array.shape[1] * channels * array.itemsize
    msg.data = array.tobytes()
    return msg


def image_to_numpy(msg) -> np.ndarray:
    """[H, W(, C)] array of an Image message (a copy)."""
    dtype, channels = ENCODINGS[msg.encoding]
    flat = np.frombuffer(bytes(msg.data), dtype=dtype)
    shape = (msg.height, msg.width) if channels == 1 else (msg.height, msg.width, channels)
    return flat.reshape(shape).copy()


def matrix_to_pose(T: np.ndarray, msg_type=Pose):
    """A Pose (of ``msg_type``) from T [4, 4]."""
    msg = msg_type()
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    msg.position.x, msg.position.y, msg.position.z = (float(v) for v in T[:3, 3])
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = float(x), float(y), float(z), float(w)
    return msg


def pose_to_matrix(pose) -> np.ndarray:
    """T [4, 4] from a Pose message."""
    T = np.eye(4)
    o = pose.orientation
    T[:3, :3] = Rotation.from_quat([o.x, o.y, o.z, o.w]).as_matrix()
    T[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return T

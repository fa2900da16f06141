"""Message types for the stand-in layer, field for field as their ROS 2 definitions (std_msgs, sensor_msgs,
geometry_msgs, vision_msgs, builtin_interfaces, std_srvs). ``nodes.ros`` exports the real ROS 2 types
instead when rclpy is installed; ``nodes.conversions`` converts either to and from numpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field


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
    distortion_model: str = ""  # the ROS 2 defaults: empty d, zero k, r and p
    d: list = field(default_factory=list)
    k: list = field(default_factory=lambda: [0.0] * 9)
    r: list = field(default_factory=lambda: [0.0] * 9)
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
class TFMessage:  # tf2_msgs/TFMessage: what tf2_ros broadcasters publish on /tf and /tf_static
    transforms: list = field(default_factory=list)  # [TransformStamped]


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

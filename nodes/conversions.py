"""Conversions between ROS 2 messages and numpy: images <-> arrays, poses <-> 4x4 matrices. They build and
read the message classes ``nodes.ros`` exports (the real ROS 2 ones where rclpy is installed, the
stand-in's otherwise), so node code calls them the same way on both.
"""

from __future__ import annotations

from array import array as Array

import numpy as np
from scipy.spatial.transform import Rotation

from nodes.ros import msgs

IDENTITY = tuple(float(v) for v in np.eye(4).ravel())  # T = I as the 16 floats of a DOUBLE_ARRAY parameter
# sensor_msgs/Image encoding -> (pixel dtype, channels)
ENCODINGS = {"rgb8": (np.uint8, 3), "bgr8": (np.uint8, 3), "mono8": (np.uint8, 1), "mono16": (np.uint16, 1),
             "16UC1": (np.uint16, 1), "32FC1": (np.float32, 1)}


def numpy_to_image(array: np.ndarray, encoding: str, header=None):
    """A sensor_msgs/Image holding ``array`` [H, W(, C)] (little-endian, rows unpadded)."""
    if encoding not in ENCODINGS:
        raise ValueError(f"unsupported image encoding {encoding!r} (supported: {', '.join(ENCODINGS)})")
    dtype, channels = ENCODINGS[encoding]
    array = np.ascontiguousarray(array, dtype=np.dtype(dtype).newbyteorder("<"))
    if array.ndim != (2 if channels == 1 else 3) or (channels > 1 and array.shape[2] != channels):
        raise ValueError(f"an image of shape {array.shape} is not {encoding}")
    msg = msgs.Image()
    if header is not None:
        msg.header = header
    msg.height, msg.width, msg.encoding = array.shape[0], array.shape[1], encoding
    msg.is_bigendian, msg.step = 0, array.shape[1] * channels * array.itemsize
    msg.data = Array("B", array.tobytes())  # uint8[] as rosidl holds it
    return msg


def image_to_numpy(msg) -> np.ndarray:
    """[H, W(, C)] array (native byte order, a copy) of a sensor_msgs/Image, honouring its ``step`` (rows may
    be padded) and ``is_bigendian``."""
    if msg.encoding not in ENCODINGS:
        raise ValueError(f"unsupported image encoding {msg.encoding!r} (supported: {', '.join(ENCODINGS)})")
    dtype, channels = ENCODINGS[msg.encoding]
    dtype = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    row = msg.width * channels * dtype.itemsize
    data = memoryview(msg.data).cast("B")
    if msg.step < row or len(data) < msg.step * msg.height:
        raise ValueError(f"image data of {len(data)} bytes, step {msg.step}, does not hold {msg.height} rows of "
                         f"{row} bytes")
    rows = np.frombuffer(data, np.uint8, msg.step * msg.height).reshape(msg.height, msg.step)[:, :row]
    flat = np.ascontiguousarray(rows).view(dtype)
    shape = (msg.height, msg.width) if channels == 1 else (msg.height, msg.width, channels)
    return flat.reshape(shape).astype(dtype.newbyteorder("="))


def camera_info(K: np.ndarray, width: int, height: int, header=None, distortion=None,
                distortion_model: str = "plumb_bob"):
    """A sensor_msgs/CameraInfo of a camera with intrinsics K [3, 3] (px) and ``distortion`` (the
    coefficients of ``distortion_model``: plumb_bob k1 k2 t1 t2 k3, rational_polynomial k1 k2 t1 t2 k3 k4 k5
    k6; None: none): ``p`` is [K | 0] (a monocular camera, rectified frame = camera frame, as DOPE's ROS node
    reads it) and ``r`` the identity."""
    msg = msgs.CameraInfo()
    if header is not None:
        msg.header = header
    msg.height, msg.width, msg.distortion_model = int(height), int(width), distortion_model
    msg.d = [float(v) for v in (distortion if distortion is not None else np.zeros(5))]
    msg.k = [float(v) for v in np.asarray(K, np.float64).ravel()]
    msg.r = [float(v) for v in np.eye(3).ravel()]
    msg.p = [float(v) for v in np.hstack([np.asarray(K, np.float64), np.zeros((3, 1))]).ravel()]
    return msg


def matrix_to_pose_msg(T: np.ndarray):
    """A geometry_msgs/Pose from T [4, 4] (metres)."""
    msg = msgs.Pose()
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    msg.position.x, msg.position.y, msg.position.z = (float(v) for v in T[:3, 3])
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = float(x), float(y), float(z), float(w)
    return msg


def matrix_to_transform(T: np.ndarray, parent: str, child: str, stamp=None):
    """A geometry_msgs/TransformStamped: the pose T [4, 4] (metres) of frame ``child`` in frame ``parent``."""
    msg = msgs.TransformStamped()
    msg.header.frame_id, msg.child_frame_id = parent, child
    if stamp is not None:
        msg.header.stamp = stamp
    pose = matrix_to_pose_msg(T)
    msg.transform.translation.x, msg.transform.translation.y, msg.transform.translation.z = (
        pose.position.x, pose.position.y, pose.position.z)
    msg.transform.rotation = pose.orientation
    return msg


def pose_msg_to_matrix(pose) -> np.ndarray:
    """T [4, 4] from a geometry_msgs/Pose; raises ValueError for a zero or non-finite quaternion."""
    T = np.eye(4)
    o = pose.orientation
    T[:3, :3] = Rotation.from_quat([o.x, o.y, o.z, o.w]).as_matrix()
    T[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return T

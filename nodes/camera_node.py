"""camera_node: publishes ``image`` (sensor_msgs/Image, rgb8) and ``camera_info`` at ``rate`` Hz.

Parameters: ``source`` = folder | oak; ``folder`` (images, in name order, looping when ``loop``; with
``wait_for_folder`` a folder that does not hold images yet is waited for, as in the generate-train-deploy
loop);
``fx fy cx cy`` (px; 0 = from the OAK's calibration or a 60 degree horizontal field of view);
``rate`` (Hz); ``frame_id``; ``width``/``height`` (OAK output size). The OAK source uses depthai 3
(when installed) and fails with a clear message when no device is attached.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from nodes.ros import Node, msgs
from pegasus_gen.errors import PegasusError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


class FolderSource:
    """Images of a folder in name order as RGB arrays."""

    def __init__(self, folder: str, loop: bool = True):
        self.paths = sorted(p for p in Path(folder).glob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.paths:
            raise PegasusError(f"camera_node: no images ({', '.join(IMAGE_SUFFIXES)}) in {folder!r}")
        self.loop, self.index = loop, 0

    def read(self) -> np.ndarray | None:
        if self.index >= len(self.paths):
            if not self.loop:
                return None
            self.index = 0
        image = cv2.imread(str(self.paths[self.index]), cv2.IMREAD_COLOR)
        if image is None:
            raise PegasusError(f"camera_node: cannot read {self.paths[self.index]}")
        self.index += 1
        return np.ascontiguousarray(image[..., ::-1])

    def intrinsics(self, width: int, height: int):
        return None


class OakSource:
    """An OAK camera's colour stream through depthai 3."""

    def __init__(self, width: int, height: int):
        try:
            import depthai as dai
        except ImportError as exc:
            raise PegasusError("camera_node: source 'oak' needs depthai (pip install depthai)") from exc
        try:
            self.pipeline = dai.Pipeline()
            cam = self.pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_A)
            self.queue = cam.requestOutput((width, height), dai.ImgFrame.Type.BGR888i).createOutputQueue()
            self.pipeline.start()
            calib = self.pipeline.getDefaultDevice().readCalibration()
            self.K = np.array(calib.getCameraIntrinsics(dai.CameraBoardSocket.CAM_A, width, height))
        except RuntimeError as exc:
            raise PegasusError(f"camera_node: no OAK camera could be opened ({exc}); is one attached?") from exc

    def read(self) -> np.ndarray:
        return np.ascontiguousarray(self.queue.get().getCvFrame()[..., ::-1])

    def intrinsics(self, width: int, height: int):
        return self.K


class CameraNode(Node):
    def __init__(self, **kwargs):
        super().__init__("camera_node", **kwargs)
        p = {name: self.declare_parameter(name, default).value for name, default in (
            ("source", "folder"), ("folder", ""), ("loop", True), ("rate", 5.0), ("frame_id", "camera"),
            ("fx", 0.0), ("fy", 0.0), ("cx", 0.0), ("cy", 0.0), ("width", 640), ("height", 480),
            ("wait_for_folder", False))}
        self.source = None
        if p["source"] == "folder":
            if not p["wait_for_folder"]:
                self.source = FolderSource(p["folder"], p["loop"])
        elif p["source"] == "oak":
            self.source = OakSource(int(p["width"]), int(p["height"]))
        else:
            raise PegasusError(f"camera_node: source must be folder or oak, got {p['source']!r}")
        self.params = p
        self.image_pub = self.create_publisher(msgs.Image, "image", 5)
        self.info_pub = self.create_publisher(msgs.CameraInfo, "camera_info", 5)
        self.frames = 0
        self.create_timer(1.0 / float(p["rate"]), self.tick)

    def camera_matrix(self, width: int, height: int) -> np.ndarray:
        p = self.params
        if p["fx"] > 0:
            return np.array([[p["fx"], 0, p["cx"] or (width - 1) / 2], [0, p["fy"] or p["fx"], p["cy"] or (height - 1) / 2],
                             [0, 0, 1]])
        K = self.source.intrinsics(width, height)
        if K is not None:
            return K
        f = (width / 2) / np.tan(np.radians(30.0))
        return np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])

    def tick(self) -> None:
        if self.source is None:  # waiting for the folder to fill
            try:
                self.source = FolderSource(self.params["folder"], self.params["loop"])
            except PegasusError:
                return
        image = self.source.read()
        if image is None:
            self.shutdown_requested = True
            return
        header = msgs.Header(frame_id=self.params["frame_id"])
        header.stamp = self.get_clock().now().to_msg()
        h, w = image.shape[:2]
        info = msgs.CameraInfo(header=header, height=h, width=w)
        info.k = self.camera_matrix(w, h).ravel().tolist()
        self.image_pub.publish(msgs.numpy_to_image(image, "rgb8", msgs.Image, header))
        self.info_pub.publish(info)
        self.frames += 1


NODE_CLASS = CameraNode


def main(args=None) -> None:
    from nodes.ros import rclpy

    rclpy.init(args=args)
    node = CameraNode()
    try:
        rclpy.spin(node)
    finally:
        node.destroy_node()
        rclpy.shutdown()

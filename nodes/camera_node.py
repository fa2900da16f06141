"""camera_node: publishes ``image`` (sensor_msgs/Image, rgb8) and ``camera_info`` at ``rate`` Hz, and
``depth`` (32FC1, metres along the optical axis, 0 = none, aligned to the image; same header as its image,
published before it) when the source has depth (``sim``, ``oak`` with ``depth``).

Parameters: ``source`` = folder | oak | sim; ``folder`` (images, in name order, looping when ``loop``; with
``wait_for_folder`` a folder that does not hold images yet is waited for, as in the generate-train-deploy
loop);
``fx fy cx cy`` (px; 0 = from the OAK's calibration or a 60 degree horizontal field of view); for ``sim``: ``host`` (the
simulated controller), ``library``, ``environment``, ``T_world_base`` and ``T_world_cam`` (16 numbers each,
row-major) — each frame renders the environment's splats and every object of the simulated cell at its
current pose (``robot_bridge.sim.twin_camera``), with the splat renderer on ``device``;
``rate`` (Hz); ``frame_id``; ``width``/``height`` (the sim's image size; an OAK's frames are ``width`` wide,
16:9); ``depth`` (the OAK's stereo depth too). With ``sim`` it also broadcasts the static transform world ->
base_link (T_world_base); robot_node adds base_link -> camera (its hand-eye). The OAK source
(``nodes.oak_camera``, depthai 2) publishes each new frame once, stamped with its exposure, with the device's
calibrated intrinsics and rational_polynomial distortion; it fails with a clear message when depthai is
missing or no device is attached.

A source has ``read()`` -> (RGB [H, W, 3] uint8, depth [H, W] float32 m or None, stamp s since the epoch or
None for now), or None when it has no new frame (``finished`` once it never will), ``intrinsics(w, h)``
(K [3, 3] or None), ``distortion`` (coefficients or None) and ``distortion_model``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nodes.conversions import IDENTITY, camera_info, matrix_to_transform, numpy_to_image
from nodes.oak_camera import OakCamera
from nodes.ros import Node, StaticTransformBroadcaster, declare, finish, msgs, run_node
from pegasus_gen.errors import PegasusError
from pegasus_gen.io.images import read_rgb

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


class FolderSource:
    """Images of a folder in name order as RGB arrays."""

    distortion, distortion_model = None, "plumb_bob"

    def __init__(self, folder: str, loop: bool = True):
        self.paths = sorted(p for p in Path(folder).glob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.paths:
            raise PegasusError(f"camera_node: no images ({', '.join(IMAGE_SUFFIXES)}) in {folder!r}")
        self.loop, self.index, self.finished = loop, 0, False

    def read(self) -> tuple[np.ndarray, None, None] | None:
        """(the next image [H, W, 3] uint8 RGB, no depth, no stamp), None at the end (then ``finished``)."""
        if self.index >= len(self.paths):
            if not self.loop:
                self.finished = True
                return None
            self.index = 0
        image = read_rgb(self.paths[self.index])
        self.index += 1
        return image, None, None

    def intrinsics(self, width: int, height: int):
        return None


PARAMETERS = (
    ("source", "folder"), ("folder", ""), ("loop", True), ("rate", 5.0), ("frame_id", "camera"),
    ("fx", 0.0), ("fy", 0.0), ("cx", 0.0), ("cy", 0.0), ("width", 640), ("height", 480),
    ("wait_for_folder", False), ("host", "127.0.0.1"), ("library", ""), ("environment", "wooden_table"),
    ("T_world_base", IDENTITY), ("T_world_cam", IDENTITY),
    ("device", "auto"), ("depth", True))


class CameraNode(Node):
    def __init__(self, **kwargs):
        super().__init__("camera_node", **kwargs)
        p = declare(self, PARAMETERS)
        self.source = None
        if p["source"] == "folder":
            if not p["wait_for_folder"]:
                self.source = FolderSource(p["folder"], p["loop"])
        elif p["source"] == "oak":
            self.source = OakCamera(int(p["width"]), bool(p["depth"]))
            if self.source.dropped_distortion > 0:
                self.get_logger().warning(f"camera_node: the OAK's thin-prism/tilt distortion terms (up to "
                                          f"{self.source.dropped_distortion:.3g}) have no place in CameraInfo")
        elif p["source"] != "sim":
            raise PegasusError(f"camera_node: source must be folder, oak or sim, got {p['source']!r}")
        self.params = p
        if p["source"] == "sim":
            w, h = int(p["width"]), int(p["height"])
            from robot_bridge.sim.twin_camera import TwinCamera

            self.source = TwinCamera(p["host"], p["library"], p["environment"], p["T_world_base"], p["T_world_cam"],
                                    w, h, self.camera_matrix(w, h), p["device"])
        self.image_pub = self.create_publisher(msgs.Image, "image", 5)
        self.info_pub = self.create_publisher(msgs.CameraInfo, "camera_info", 5)
        self.depth_pub = self.create_publisher(msgs.Image, "depth", 5)
        self.frames = 0
        if p["source"] == "sim":
            self.tf_static = StaticTransformBroadcaster(self)
            self.tf_static.sendTransform(matrix_to_transform(np.array(p["T_world_base"]).reshape(4, 4), "world",
                                                             "base_link", self.get_clock().now().to_msg()))
        self.create_timer(1.0 / float(p["rate"]), self.tick)

    def camera_matrix(self, width: int, height: int) -> np.ndarray:
        p = self.params
        if p["fx"] > 0:
            return np.array([[p["fx"], 0, p["cx"] or (width - 1) / 2],
                             [0, p["fy"] or p["fx"], p["cy"] or (height - 1) / 2],
                             [0, 0, 1]])
        K = self.source.intrinsics(width, height) if self.source is not None else None
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
        frame = self.source.read()
        if frame is None:
            if self.source.finished:  # a folder played once: this node's job is over
                finish(self)
            return  # no new frame yet
        image, depth, stamp = frame
        header = msgs.Header(frame_id=self.params["frame_id"])
        if stamp is None:
            header.stamp = self.get_clock().now().to_msg()
        else:
            header.stamp.sec, header.stamp.nanosec = divmod(int(round(stamp * 1e9)), 1_000_000_000)
        h, w = image.shape[:2]
        info = camera_info(self.camera_matrix(w, h), w, h, header, self.source.distortion,
                           self.source.distortion_model)
        if depth is not None:
            self.depth_pub.publish(numpy_to_image(depth, "32FC1", header))
        self.image_pub.publish(numpy_to_image(image, "rgb8", header))
        self.info_pub.publish(info)
        self.frames += 1


    def destroy_node(self) -> None:
        if isinstance(self.source, OakCamera):
            self.source.close()
        super().destroy_node()


NODE_CLASS = CameraNode


def main(args=None) -> None:
    """Console entry point (``ros2 run`` style)."""
    run_node(NODE_CLASS, args)

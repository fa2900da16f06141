"""camera_node: publishes ``image`` (sensor_msgs/Image, rgb8) and ``camera_info`` at ``rate`` Hz, and
``depth`` (32FC1, metres along the optical axis, 0 = none; same header as its image, published before it)
when the source has depth (``sim``).

Parameters: ``source`` = folder | oak | sim; ``folder`` (images, in name order, looping when ``loop``; with
``wait_for_folder`` a folder that does not hold images yet is waited for, as in the generate-train-deploy
loop);
``fx fy cx cy`` (px; 0 = from the OAK's calibration or a 60 degree horizontal field of view); for ``sim``: ``host`` (the
simulated controller), ``library``, ``environment``, ``T_world_base`` and ``T_world_cam`` (16 numbers each,
row-major) — each frame renders the environment's splats and every object of the simulated cell at its
current pose (asset name = the sim object's name up to '#'), with the splat renderer on ``device``;
``rate`` (Hz); ``frame_id``; ``width``/``height`` (OAK output size). With ``sim`` it also broadcasts the
static transform world -> base_link (T_world_base); robot_node adds base_link -> camera (its hand-eye). The
OAK source uses depthai 3 (when installed) and fails with a clear message when no device is attached.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from nodes.conversions import IDENTITY, camera_info, matrix_to_transform, numpy_to_image
from nodes.ros import Node, StaticTransformBroadcaster, declare, finish, msgs, run_node
from pegasus_gen.errors import PegasusError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


class FolderSource:
    """Images of a folder in name order as RGB arrays."""

    def __init__(self, folder: str, loop: bool = True):
        self.paths = sorted(p for p in Path(folder).glob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.paths:
            raise PegasusError(f"camera_node: no images ({', '.join(IMAGE_SUFFIXES)}) in {folder!r}")
        self.loop, self.index = loop, 0

    def read(self) -> tuple[np.ndarray, None] | None:
        """(the next image [H, W, 3] uint8 RGB, no depth), None at the end."""
        if self.index >= len(self.paths):
            if not self.loop:
                return None
            self.index = 0
        image = cv2.imread(str(self.paths[self.index]), cv2.IMREAD_COLOR)
        if image is None:
            raise PegasusError(f"camera_node: cannot read {self.paths[self.index]}")
        self.index += 1
        return np.ascontiguousarray(image[..., ::-1]), None

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

    def read(self) -> tuple[np.ndarray, None]:
        return np.ascontiguousarray(self.queue.get().getCvFrame()[..., ::-1]), None

    def intrinsics(self, width: int, height: int):
        return self.K


class SimSource:
    """Renders the simulated cell from splats: the environment plus each object at the pose the simulated
    controller reports (its PyBullet state), so the image is the digital twin of the physics."""

    def __init__(self, host: str, library: str, environment: str, T_world_base, T_world_cam, width: int,
                 height: int, K: np.ndarray, device: str):
        from pegasus_gen.assets.library import AssetLibrary
        from robot_bridge.sim.client import dashboard_command, sim_object_pose

        self.command = lambda text: dashboard_command(host, text)
        self.object_pose = lambda name: sim_object_pose(host, name)
        self.library = AssetLibrary(library or None)
        self.environment = self.library.get(environment).splats.with_label(0)
        self.T_world_base = np.array(T_world_base, dtype=np.float64).reshape(4, 4)
        self.T_cam_world = np.linalg.inv(np.array(T_world_cam, dtype=np.float64).reshape(4, 4))
        self.width, self.height, self.K, self.device = width, height, K, device
        self.splats = {}

    def object_poses(self) -> dict[str, np.ndarray]:
        """{sim object name: T_world_obj}."""
        poses = {}
        for name in self.command("sim list").split():
            try:
                poses[name] = self.T_world_base @ self.object_pose(name)
            except LookupError:  # removed (by the evaluator) since the listing
                continue
        return poses

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """The cell as the camera sees it: RGB [H, W, 3] uint8 and depth [H, W] float32 metres (0 = none)."""
        from pegasus_gen.io.images import rgb_to_uint8
        from pegasus_gen.render.renderer import render

        parts = [self.environment]
        for k, (name, T) in enumerate(self.object_poses().items()):
            asset = name.split("#")[0]
            if asset not in self.splats:
                self.splats[asset] = self.library.get(asset).splats
            parts.append(self.splats[asset].transformed(T).with_label(k + 1))
        out = render(parts, self.K, self.T_cam_world, self.width, self.height, device=self.device)
        return rgb_to_uint8(out.rgb), np.nan_to_num(out.depth, nan=0.0, posinf=0.0).astype(np.float32)

    def intrinsics(self, width: int, height: int):
        return self.K


PARAMETERS = (
    ("source", "folder"), ("folder", ""), ("loop", True), ("rate", 5.0), ("frame_id", "camera"),
    ("fx", 0.0), ("fy", 0.0), ("cx", 0.0), ("cy", 0.0), ("width", 640), ("height", 480),
    ("wait_for_folder", False), ("host", "127.0.0.1"), ("library", ""), ("environment", "wooden_table"),
    ("T_world_base", IDENTITY), ("T_world_cam", IDENTITY),
    ("device", "auto"))


class CameraNode(Node):
    def __init__(self, **kwargs):
        super().__init__("camera_node", **kwargs)
        p = declare(self, PARAMETERS)
        self.source = None
        if p["source"] == "folder":
            if not p["wait_for_folder"]:
                self.source = FolderSource(p["folder"], p["loop"])
        elif p["source"] == "oak":
            self.source = OakSource(int(p["width"]), int(p["height"]))
        elif p["source"] != "sim":
            raise PegasusError(f"camera_node: source must be folder, oak or sim, got {p['source']!r}")
        self.params = p
        if p["source"] == "sim":
            w, h = int(p["width"]), int(p["height"])
            self.source = SimSource(p["host"], p["library"], p["environment"], p["T_world_base"], p["T_world_cam"],
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
        if frame is None:  # a folder played once: this node's job is over
            finish(self)
            return
        image, depth = frame
        header = msgs.Header(frame_id=self.params["frame_id"])
        header.stamp = self.get_clock().now().to_msg()
        h, w = image.shape[:2]
        info = camera_info(self.camera_matrix(w, h), w, h, header)
        if depth is not None:
            self.depth_pub.publish(numpy_to_image(depth, "32FC1", header))
        self.image_pub.publish(numpy_to_image(image, "rgb8", header))
        self.info_pub.publish(info)
        self.frames += 1


NODE_CLASS = CameraNode


def main(args=None) -> None:
    """Console entry point (``ros2 run`` style)."""
    run_node(NODE_CLASS, args)

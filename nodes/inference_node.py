"""inference_node: DOPE poses from camera images, refined with depth when the camera has it, or against the RGB
image itself when it has none.

Subscribes ``image`` (rgb8), ``camera_info`` (K) and, with ``refine``, ``depth`` (32FC1 metres or 16UC1
mm, aligned to the image; paired with its image by header stamp). Publishes for each image ``object_pose_raw``
(geometry_msgs/PoseStamped of the best-scoring instance as DOPE + PnP give it, camera frame, metres),
``object_pose_refined`` (with ``refine``: the best-scoring instance whose depth refinement was accepted,
refined; with ``refine_rgb``: the best instance refined against the image, scored by its detection score times
its outline's support, when it reaches ``min_score``), ``object_pose`` (what the robot uses: the raw pose, or with
``use_pose`` = refined the refined one and nothing when there is none), ``detections``
(vision_msgs/Detection3DArray: every instance with its score and model box, refined where accepted) and
``overlay`` (the image with the posed boxes and keypoints).
Parameters: ``model`` (ONNX export or checkpoint; empty: the path that arrives on the ``model`` topic, as
trainer_node publishes it), ``device`` (cpu | cuda | auto), ``min_score``, ``refine`` (bool: with depth),
``refine_rgb`` (the object's mesh, PLY/OBJ in its model frame, ``mesh_scale`` metres per unit: refine against
the image, ``refine_rgb.refine_rgb``; empty: off), ``zoom`` (a zoom network of the same object, ``pegasus
train-zoom``, or several comma-separated, applied in turn: every pose moved by its zoomed second look first and
scored by its detection score times its outline's support there, ``ObjectPose.score``; empty: off),
``use_pose`` (raw | refined),
``max_images`` (> 0: end after that many images). Broadcasts on /tf each instance's pose (refined where accepted)
as the transform from the image's frame to ``<object>_<k>`` (k by score).
"""

from __future__ import annotations

import numpy as np

from dope_training.infer import DopeModel, rgb_refined
from dope_training.overlay import draw_poses
from dope_training.refine_rgb import read_mesh
from nodes.conversions import image_to_numpy, matrix_to_pose_msg, matrix_to_transform, numpy_to_image
from nodes.ros import Node, TransformBroadcaster, declare, finish, latched, msgs, run_node
from pegasus_gen.errors import PegasusError

PENDING_FRAMES = 4  # images or depth images kept while waiting for their partner


PARAMETERS = (("model", ""), ("device", "cpu"), ("min_score", 0.1), ("max_images", 0), ("refine", False),
              ("refine_rgb", ""), ("mesh_scale", 1.0), ("zoom", ""), ("use_pose", "raw"))


class InferenceNode(Node):
    def __init__(self, **kwargs):
        super().__init__("inference_node", **kwargs)
        p = declare(self, PARAMETERS)
        model, self.device, self.min_score = p["model"], p["device"], p["min_score"]
        self.max_images, self.refine, self.use_pose = p["max_images"], p["refine"], p["use_pose"]
        if self.use_pose not in ("raw", "refined"):
            raise PegasusError(f"inference_node: use_pose must be raw or refined, got {self.use_pose!r}")
        if self.refine and p["refine_rgb"]:
            raise PegasusError("inference_node: refine (with depth) and refine_rgb (against the image): choose one")
        if self.use_pose == "refined" and not (self.refine or p["refine_rgb"]):
            raise PegasusError("inference_node: use_pose refined needs refine true (and a depth topic) or a "
                               "refine_rgb mesh")
        self.mesh = read_mesh(p["refine_rgb"], p["mesh_scale"]) if p["refine_rgb"] else None
        self.zoom = [z.strip() for z in p["zoom"].split(",") if z.strip()] or None
        self.model = DopeModel(model, device=self.device, zoom=self.zoom) if model else None
        self.create_subscription(msgs.String, "model", self.on_model, latched())
        self.K = None
        self.pose_pub = self.create_publisher(msgs.PoseStamped, "object_pose", 5)
        self.raw_pub = self.create_publisher(msgs.PoseStamped, "object_pose_raw", 5)
        self.refined_pub = self.create_publisher(msgs.PoseStamped, "object_pose_refined", 5)
        self.detections_pub = self.create_publisher(msgs.Detection3DArray, "detections", 5)
        self.overlay_pub = self.create_publisher(msgs.Image, "overlay", 2)
        self.tf = TransformBroadcaster(self)
        self.create_subscription(msgs.CameraInfo, "camera_info", self.on_info, 5)
        self.create_subscription(msgs.Image, "image", self.on_image, 2)
        if self.refine:
            self.create_subscription(msgs.Image, "depth", self.on_depth, 2)
        self.pending = {}  # header stamp -> {"image": msg, "depth": msg}
        self.images = 0

    def on_model(self, msg) -> None:
        self.model = DopeModel(msg.data, device=self.device, zoom=self.zoom)
        self.get_logger().info(f"inference_node: using {msg.data}")

    def on_info(self, msg) -> None:
        self.K = np.array(msg.k, dtype=np.float64).reshape(3, 3)

    def on_depth(self, msg) -> None:
        self._pair(msg, "depth")

    def on_image(self, msg) -> None:
        if not self.refine:
            self.process(msg, None)
        else:
            self._pair(msg, "image")

    def _pair(self, msg, kind: str) -> None:
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        entry = self.pending.setdefault(stamp, {})
        entry[kind] = msg
        if len(entry) == 2:
            del self.pending[stamp]
            depth = image_to_numpy(entry["depth"]).astype(np.float64)
            self.process(entry["image"], depth / 1000.0 if entry["depth"].encoding == "16UC1" else depth)
        for old in sorted(self.pending)[:-PENDING_FRAMES]:
            del self.pending[old]

    def process(self, msg, depth_m: np.ndarray | None) -> None:
        """Estimate, refine (with ``depth_m`` [H, W] metres, or against the image) and publish the poses of one
        image."""
        if self.K is None or self.model is None:
            return  # no camera_info or no model yet
        image = image_to_numpy(msg)
        poses = self.model.estimate(image, self.K, min_score=self.min_score, depth_m=depth_m, mesh=self.mesh)
        self.images += 1
        best = {"raw": next((p.T for p in poses if p.T is not None), None),
                "refined": next((p.refined for p in poses if p.refined is not None), None)}
        if self.mesh is not None:
            poses = rgb_refined(poses, self.min_score)
            best["refined"] = poses[0].T if poses else None
        obj = self.model.object
        array = msgs.Detection3DArray(header=msg.header)
        transforms = []
        for k, pose in enumerate(poses):
            T = pose.refined if pose.refined is not None else pose.T
            transforms.append(matrix_to_transform(T, msg.header.frame_id, f"{obj.name}_{k}", msg.header.stamp))
            hypothesis = msgs.ObjectHypothesisWithPose()
            hypothesis.hypothesis.class_id, hypothesis.hypothesis.score = obj.name, pose.score
            hypothesis.pose.pose = matrix_to_pose_msg(T)
            detection = msgs.Detection3D(header=msg.header, results=[hypothesis], id=obj.name)
            detection.bbox.center = matrix_to_pose_msg(T)
            detection.bbox.size.x, detection.bbox.size.y, detection.bbox.size.z = (float(v) for v in obj.bbox_size)
            array.detections.append(detection)
        self.detections_pub.publish(array)
        if transforms:
            self.tf.sendTransform(transforms)
        overlay = draw_poses(image, self.K, poses, obj)
        self.overlay_pub.publish(numpy_to_image(overlay, "rgb8", msg.header))
        stamped = {name: msgs.PoseStamped(header=msg.header, pose=matrix_to_pose_msg(T))
                   for name, T in best.items() if T is not None}
        for name, publisher in (("raw", self.raw_pub), ("refined", self.refined_pub)):
            if name in stamped:
                publisher.publish(stamped[name])
        if self.use_pose in stamped:
            self.pose_pub.publish(stamped[self.use_pose])
        if self.max_images and self.images >= self.max_images:
            finish(self)


NODE_CLASS = InferenceNode


def main(args=None) -> None:
    """Console entry point (``ros2 run`` style)."""
    run_node(NODE_CLASS, args)

"""inference_node: DOPE poses from camera images.

Subscribes ``image`` (rgb8) and ``camera_info`` (K); publishes for each image ``object_pose``
(geometry_msgs/PoseStamped of the best-scoring instance, camera frame, metres), ``detections``
(vision_msgs/Detection3DArray: every instance with its score and model box) and ``overlay`` (the image with
the posed boxes and keypoints). Parameters: ``model`` (ONNX export or checkpoint; empty: the path that arrives on the
``model`` topic, as trainer_node publishes it), ``device`` (cpu | cuda | auto), ``min_score``,
``max_images`` (> 0: ask the launch to end after that many images).
"""

from __future__ import annotations

import numpy as np

from dope_training.infer import DopeModel
from dope_training.overlay import draw_poses
from nodes.ros import Node, latched, msgs, run_node


class InferenceNode(Node):
    def __init__(self, **kwargs):
        super().__init__("inference_node", **kwargs)
        model = self.declare_parameter("model", "").value
        self.device = self.declare_parameter("device", "cpu").value
        self.min_score = float(self.declare_parameter("min_score", 0.1).value)
        self.max_images = int(self.declare_parameter("max_images", 0).value)
        self.model = DopeModel(model, device=self.device) if model else None
        self.create_subscription(msgs.String, "model", self.on_model, latched())
        self.K = None
        self.pose_pub = self.create_publisher(msgs.PoseStamped, "object_pose", 5)
        self.detections_pub = self.create_publisher(msgs.Detection3DArray, "detections", 5)
        self.overlay_pub = self.create_publisher(msgs.Image, "overlay", 2)
        self.create_subscription(msgs.CameraInfo, "camera_info", self.on_info, 5)
        self.create_subscription(msgs.Image, "image", self.on_image, 2)
        self.images = 0

    def on_model(self, msg) -> None:
        self.model = DopeModel(msg.data, device=self.device)
        self.get_logger().info(f"inference_node: using {msg.data}")

    def on_info(self, msg) -> None:
        self.K = np.array(msg.k, dtype=np.float64).reshape(3, 3)

    def on_image(self, msg) -> None:
        if self.K is None or self.model is None:
            return  # no camera_info or no model yet
        image = msgs.image_to_numpy(msg)
        poses = self.model.estimate(image, self.K, min_score=self.min_score)
        self.images += 1
        obj = self.model.object
        array = msgs.Detection3DArray(header=msg.header)
        for pose in poses:
            hypothesis = msgs.ObjectHypothesisWithPose()
            hypothesis.hypothesis.class_id, hypothesis.hypothesis.score = obj.name, pose.score
            hypothesis.pose.pose = msgs.matrix_to_pose(pose.T, msgs.Pose)
            detection = msgs.Detection3D(header=msg.header, results=[hypothesis], id=obj.name)
            detection.bbox.center = msgs.matrix_to_pose(pose.T, msgs.Pose)
            detection.bbox.size.x, detection.bbox.size.y, detection.bbox.size.z = (float(v) for v in obj.bbox_size)
            array.detections.append(detection)
        self.detections_pub.publish(array)
        overlay = draw_poses(image, self.K, poses, obj)
        self.overlay_pub.publish(msgs.numpy_to_image(overlay, "rgb8", msgs.Image, msg.header))
        if poses:
            self.pose_pub.publish(msgs.PoseStamped(header=msg.header, pose=msgs.matrix_to_pose(poses[0].T, msgs.Pose)))
        if self.max_images and self.images >= self.max_images:
            self.shutdown_requested = True


NODE_CLASS = InferenceNode


def main(args=None) -> None:
    """Console entry point (``ros2 run`` style)."""
    run_node(NODE_CLASS, args)

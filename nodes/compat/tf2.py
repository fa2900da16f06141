"""tf2_ros's two broadcasters, for nodes written against rclpy and tf2_ros."""

from __future__ import annotations

from nodes.compat.node import Node
from nodes.compat.qos import DurabilityPolicy, QoSProfile
from nodes.msgs import TFMessage


class TransformBroadcaster:
    """tf2_ros.TransformBroadcaster: tf2_msgs/TFMessage on /tf, as the real one sends (``message`` and
    ``qos_profile``: the TFMessage class and QoS class of the rclpy in use)."""

    message, qos_profile = TFMessage, QoSProfile

    def __init__(self, node: Node, qos=None):
        self.publisher = node.create_publisher(self.message, "/tf", qos or self.qos_profile(depth=100))

    def sendTransform(self, transform) -> None:  # noqa: N802 - tf2_ros's name
        transforms = transform if isinstance(transform, (list, tuple)) else [transform]
        self.publisher.publish(self.message(transforms=list(transforms)))


class StaticTransformBroadcaster:
    """tf2_ros.StaticTransformBroadcaster: every static transform sent so far (the newest per child frame) in
    one TFMessage, latched on /tf_static."""

    message, qos_profile, transient_local = TFMessage, QoSProfile, DurabilityPolicy.TRANSIENT_LOCAL

    def __init__(self, node: Node, qos=None):
        self.publisher = node.create_publisher(
            self.message, "/tf_static", qos or self.qos_profile(depth=1, durability=self.transient_local))
        self.transforms: dict[str, object] = {}

    def sendTransform(self, transform) -> None:  # noqa: N802 - tf2_ros's name
        for t in transform if isinstance(transform, (list, tuple)) else [transform]:
            self.transforms[t.child_frame_id] = t
        self.publisher.publish(self.message(transforms=list(self.transforms.values())))

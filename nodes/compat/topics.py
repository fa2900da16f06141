"""rclpy.publisher and rclpy.subscription: the endpoints of a topic, matched by type and QoS."""

from __future__ import annotations

import collections
from dataclasses import dataclass

from nodes.compat.exceptions import RCLError
from nodes.compat.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, incompatible_policy


class Publisher:
    def __init__(self, node, msg_type, topic: str, qos: QoSProfile):
        self.node, self.msg_type, self.topic_name, self.qos = node, msg_type, topic, qos

    def publish(self, msg) -> None:
        if not isinstance(msg, self.msg_type):
            raise TypeError(f"{self.topic_name}: publish() expects {self.msg_type.__name__}, got {type(msg).__name__}")
        ctx = self.node.context
        with ctx.lock:
            if self.qos.durability == DurabilityPolicy.TRANSIENT_LOCAL:
                ctx.latched[self.topic_name][self] = msg
            for sub in ctx.subscriptions.get(self.topic_name, []):
                if matched(self, sub):
                    sub.queue.append(msg)
        ctx.notify()

    def get_subscription_count(self) -> int:
        return sum(matched(self, sub) for sub in self.node.context.subscriptions.get(self.topic_name, []))

    def destroy(self) -> None:
        with self.node.context.lock:
            self.node.context.latched.get(self.topic_name, {}).pop(self, None)  # its stored message goes with it
            self.node.context.publishers[self.topic_name].remove(self)
        self.node.publishers.remove(self)


@dataclass
class TopicEndpointInfo:
    """rclpy.topic_endpoint_info.TopicEndpointInfo of a publisher (the fields the nodes read)."""

    node_name: str
    node_namespace: str
    topic_type: str
    qos_profile: QoSProfile


def matched(pub: Publisher, sub: "Subscription") -> bool:
    """Whether ``sub`` receives what ``pub`` publishes: same topic type and compatible QoS."""
    return pub.msg_type is sub.msg_type and incompatible_policy(pub.qos, sub.qos) is None


def warn_unmatched(pub: Publisher, sub: "Subscription") -> None:
    """Log on both sides, as rclpy's default event handlers do, why ``pub`` and ``sub`` on one topic do not
    match (each names the topic as its node gave it)."""
    if pub.msg_type is not sub.msg_type:
        for entity in (sub, pub):
            entity.node.get_logger().warning(
                f"Incompatible type on topic '{entity.topic}', no messages will be sent to it.")
    elif (policy := incompatible_policy(pub.qos, sub.qos)) is not None:
        sub.node.get_logger().warning(
            f"New publisher discovered on topic '{sub.topic}', offering incompatible QoS. No messages will be "
            f"received from it. Last incompatible policy: {policy}")
        pub.node.get_logger().warning(
            f"New subscription discovered on topic '{pub.topic}', requesting incompatible QoS. No messages "
            f"will be sent to it. Last incompatible policy: {policy}")


def check_one_type(context, entity) -> None:
    """RCLError, as Fast DDS's one participant per context gives, when ``entity``'s topic already has an
    endpoint of another type in the same context (in separate contexts, as in separate processes, they only
    do not match)."""
    for table in (context.publishers, context.subscriptions):
        for other in table.get(entity.topic_name, []):
            if other.node.context is entity.node.context and other.msg_type is not entity.msg_type:
                raise RCLError(f"create_{type(entity).__name__.lower()}() called for existing topic name "
                               f"{entity.topic_name} with incompatible type {entity.msg_type.TYPE_NAME}")


class Subscription:
    def __init__(self, node, msg_type, topic: str, callback, qos: QoSProfile):
        self.node, self.msg_type, self.topic_name, self.callback = node, msg_type, topic, callback
        depth = None if qos.history == HistoryPolicy.KEEP_ALL else max(qos.depth, 1)
        self.queue: collections.deque = collections.deque(maxlen=depth)
        self.qos = qos
        if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL:  # a volatile reader gets no history
            for pub, message in node.context.latched.get(topic, {}).items():
                if matched(pub, self):
                    self.queue.append(message)

    def destroy(self) -> None:
        with self.node.context.lock:
            self.node.context.subscriptions[self.topic_name].remove(self)
        self.node.subscriptions.remove(self)

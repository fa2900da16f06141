"""recorder_node: records every topic of the graph into a rosbag2 bag (MCAP storage, ``nodes.bag``), as
``ros2 bag record -a -s mcap`` does: it looks for new topics every ``discovery_period`` seconds, subscribes to
each with the QoS its publishers offer (reliable only when all of them are, transient local likewise, so a
latched topic such as /tf_static arrives too), and writes each message as CDR, stamped with the time it was
received. The bag is closed (index and metadata.yaml written) when the node is destroyed, at the end of a
launch or on Ctrl-C.

Parameters: ``path`` (the bag directory to create; ``NAME.mcap`` creates ``NAME/NAME.mcap``; an existing
one is refused), ``discovery_period`` (s).
"""

from __future__ import annotations

from nodes.bag import BagWriter, offered_qos
from nodes.ros import DurabilityPolicy, Node, QoSProfile, ReliabilityPolicy, declare, message_type, run_node, serialize
from pegasus_gen.errors import PegasusError

PARAMETERS = (("path", "episode"), ("discovery_period", 0.1))
DEPTH = 100  # messages a subscription holds while the executor is busy


class RecorderNode(Node):
    def __init__(self, **kwargs):
        super().__init__("recorder_node", **kwargs)
        p = declare(self, PARAMETERS)
        if not p["path"]:
            raise PegasusError("recorder_node: give path (the bag to create)")
        self.bag = BagWriter(p["path"])
        self.get_logger().info(f"recording every topic to {self.bag.path}")
        self.create_timer(float(p["discovery_period"]), self.discover)
        self.discover()

    def discover(self) -> None:
        """Subscribe to each topic that has publishers and is not recorded yet."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self.bag.counts:
                continue
            offered = [info.qos_profile for info in self.get_publishers_info_by_topic(topic)]
            if not offered or len(types) != 1:  # no publisher yet, or a topic of two types (nothing passes)
                continue
            reliable = all(q.reliability == ReliabilityPolicy.RELIABLE for q in offered)
            transient_local = all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
            self.bag.add_topic(topic, types[0], [
                offered_qos(q.reliability == ReliabilityPolicy.RELIABLE,
                            q.durability == DurabilityPolicy.TRANSIENT_LOCAL, q.depth) for q in offered])
            qos = QoSProfile(depth=DEPTH,
                             reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL if transient_local
                             else DurabilityPolicy.VOLATILE)
            self.create_subscription(message_type(types[0]), topic, self.writer_for(topic), qos)

    def writer_for(self, topic: str):
        def write(msg) -> None:
            self.bag.write(topic, self.get_clock().now().nanoseconds, serialize(msg))
        return write

    def destroy_node(self) -> None:
        self.bag.close()
        counts = ", ".join(f"{topic} {n}" for topic, n in sorted(self.bag.counts.items()))
        self.get_logger().info(f"bag {self.bag.path}: {counts or 'no messages'}")
        super().destroy_node()


NODE_CLASS = RecorderNode


def main(args=None) -> None:
    """Console entry point (``ros2 run`` style)."""
    run_node(NODE_CLASS, args)

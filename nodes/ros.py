"""The ROS 2 API the nodes are written against: the real rclpy and message packages when they import,
otherwise the stand-in layer (``nodes.compat``, ``nodes.msgs``). Nodes import everything from here:

    from nodes.ros import rclpy, Node, msgs, QoSProfile
"""

from __future__ import annotations

try:  # pragma: no cover - exercised only where ROS 2 is installed
    import types

    import rclpy
    from geometry_msgs.msg import Pose, PoseStamped, TransformStamped
    from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message as serialize
    from rosidl_runtime_py.utilities import get_message as message_type
    from sensor_msgs.msg import CameraInfo, Image
    from std_msgs.msg import Header, String
    from std_srvs.srv import Trigger
    from tf2_msgs.msg import TFMessage
    from tf2_ros import StaticTransformBroadcaster, TransformBroadcaster
    from vision_msgs.msg import Detection3D, Detection3DArray, ObjectHypothesisWithPose

    msgs = types.SimpleNamespace(Pose=Pose, PoseStamped=PoseStamped, TransformStamped=TransformStamped,
                                 CameraInfo=CameraInfo, Image=Image, Header=Header, String=String, Trigger=Trigger,
                                 TFMessage=TFMessage,
                                 Detection3D=Detection3D, Detection3DArray=Detection3DArray,
                                 ObjectHypothesisWithPose=ObjectHypothesisWithPose)
    REAL_ROS = True
except ImportError:
    from nodes import compat as rclpy
    from nodes import msgs
    from nodes.compat import (
        DurabilityPolicy,
        MultiThreadedExecutor,
        Node,
        Parameter,
        QoSProfile,
        ReliabilityPolicy,
        SingleThreadedExecutor,
        StaticTransformBroadcaster,
        TransformBroadcaster,
    )
    from nodes.msgs import message_class as message_type
    from nodes.msgs import serialize

    REAL_ROS = False



def latched(depth: int = 1):
    """QoS of a topic whose last message reaches late subscribers too (transient local)."""
    return QoSProfile(depth=depth, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def declare(node, parameters: tuple) -> dict:
    """{name: value} of ``parameters`` ((name, default), ...) declared on ``node``, each statically typed by its
    default as rclpy does (a float parameter refuses an int, an array parameter a string): a node module's
    ``PARAMETERS`` table, which tests check the launch files against."""
    return {name: node.declare_parameter(name, default).value for name, default in parameters}


def finish(node) -> None:
    """End ``node`` the rclpy way once its job is over: shut its context down, so that spin returns and its
    process (``run_node``) exits. A launch file ends the whole launch with it through ``on_exit=Shutdown()``
    on the node's action."""
    rclpy.try_shutdown(context=node.context)


def run_node(node_class, args=None) -> None:
    """init, spin one node until its context shuts down (``finish``) or Ctrl-C, clean up: each node module's
    ``main``."""
    rclpy.init(args=args)
    node = node_class()
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


__all__ = ["run_node", "finish", "declare", "TransformBroadcaster", "StaticTransformBroadcaster", "latched", "rclpy",
           "Node", "QoSProfile", "ReliabilityPolicy", "DurabilityPolicy", "MultiThreadedExecutor",
           "SingleThreadedExecutor", "Parameter", "msgs", "message_type", "serialize", "REAL_ROS"]

"""The ROS 2 API the nodes are written against: the real rclpy and message packages when they all import (a
ROS 2 install), otherwise the stand-in layer (``nodes.compat``, ``nodes.msgs``); ``PEGASUS_ROS=rclpy`` takes
the real rclpy from the ros extra's wheels, with tf2_msgs and vision_msgs as ``nodes.ros_interfaces`` builds
them and tf2_ros's broadcasters from here. Nodes import everything from here:

    from nodes.ros import rclpy, Node, msgs, QoSProfile
"""

from __future__ import annotations

import importlib
import os
import signal
import sys
import types

from pegasus_gen.errors import PegasusError

# Which implementation: "auto" (the real rclpy where ROS 2 is installed, with tf2_ros and vision_msgs: a ROS 2
# install or workspace; else the stand-in), "rclpy" (the real rclpy with the message packages there are: where
# tf2_msgs or vision_msgs is missing, a node that needs it refuses to start, naming it), or "stand-in".
CHOICE = os.environ.get("PEGASUS_ROS", "auto")
if CHOICE not in ("auto", "rclpy", "stand-in"):
    raise ImportError(f"PEGASUS_ROS must be auto, rclpy or stand-in, got {CHOICE!r}")
# rosidl's message classes check their fields on assignment only with this set (read as each message package is
# imported): the real nodes are then held to the same rules as the stand-in's
os.environ.setdefault("ROS_PYTHON_CHECK_FIELDS", "1")


def _no_wheel(name: str, package: str) -> ImportError:
    return ImportError(f"{name} needs ROS 2's {package}, which has no wheel: build it into this environment "
                       "(python -m nodes.ros_interfaces), run in a ROS 2 install or on the stand-in "
                       "(PEGASUS_ROS=stand-in)")


class _NotInRosWheels:
    """Stands for a tf2_ros broadcaster under PEGASUS_ROS=rclpy without tf2_msgs: making one raises an
    ImportError naming tf2_msgs."""

    def __init__(self, package: str, name: str):
        self.package, self.name = package, name

    def __call__(self, *args, **kwargs):
        raise _no_wheel(self.name, self.package)


class _Messages(types.SimpleNamespace):
    """The message classes by name; one whose package has no wheel (``missing``: {name: package}) raises an
    ImportError naming the package when a node asks for it."""

    missing: dict = {}

    def __getattr__(self, name: str):
        if name in self.missing:
            raise _no_wheel(name, self.missing[name])
        raise AttributeError(name)


def _real_message_type(type_name: str) -> type:
    """The rosidl class of ``"pkg/msg/Name"`` (rosidl_runtime_py.utilities.get_message, which has no wheel)."""
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def _optional(module: str, names: tuple[str, ...]) -> dict:
    """{name: the real thing} from ``module``; under PEGASUS_ROS=rclpy, where it does not import, {} with the
    names filed in ``_Messages.missing`` (elsewhere the ImportError goes on: auto falls back to the stand-in)."""
    try:
        loaded = importlib.import_module(module)
        return {name: getattr(loaded, name) for name in names}
    except ImportError:
        if CHOICE != "rclpy":
            raise
        _Messages.missing.update({name: module.split(".")[0] for name in names})
        return {}


def _ros2_installed() -> bool:
    """Whether everything the nodes use imports from ROS 2 (found, not imported: the wheels alone lack tf2_ros)."""
    import importlib.util

    return all(importlib.util.find_spec(name) is not None
               for name in ("rclpy", "tf2_ros", "tf2_msgs", "vision_msgs", "sensor_msgs", "std_srvs"))


try:
    if CHOICE == "stand-in" or (CHOICE == "auto" and not _ros2_installed()):
        raise ImportError(f"PEGASUS_ROS={CHOICE}")
    import rclpy
    from geometry_msgs.msg import Pose, PoseStamped, TransformStamped
    from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message as serialize
    from sensor_msgs.msg import CameraInfo, Image
    from std_msgs.msg import Header, String
    from std_srvs.srv import Trigger

    message_type = _real_message_type
    msgs = _Messages(Pose=Pose, PoseStamped=PoseStamped, TransformStamped=TransformStamped, CameraInfo=CameraInfo,
                     Image=Image, Header=Header, String=String, Trigger=Trigger,
                     **_optional("tf2_msgs.msg", ("TFMessage",)),
                     **_optional("vision_msgs.msg", ("Detection3D", "Detection3DArray", "ObjectHypothesisWithPose")))
    try:
        from tf2_ros import StaticTransformBroadcaster, TransformBroadcaster
    except ImportError:
        if CHOICE != "rclpy":
            raise
        if "TFMessage" in _Messages.missing:
            StaticTransformBroadcaster = _NotInRosWheels("tf2_msgs", "StaticTransformBroadcaster")
            TransformBroadcaster = _NotInRosWheels("tf2_msgs", "TransformBroadcaster")
        else:  # tf2_msgs built by nodes.ros_interfaces: tf2_ros's two broadcasters are a publisher each
            from nodes import compat as _compat

            class TransformBroadcaster(_compat.TransformBroadcaster):
                message, qos_profile = msgs.TFMessage, QoSProfile

            class StaticTransformBroadcaster(_compat.StaticTransformBroadcaster):
                message, qos_profile, transient_local = msgs.TFMessage, QoSProfile, DurabilityPolicy.TRANSIENT_LOCAL
    REAL_ROS = True
except ImportError:
    if CHOICE == "rclpy":
        raise
    from nodes import compat as rclpy
    from nodes import msgs
    from nodes.compat import (
        DurabilityPolicy,
        ExternalShutdownException,
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
    ``main``. A node that refuses its parameters (PegasusError) ends the process with one line and exit code 2."""
    if REAL_ROS:  # Ctrl-C: rclpy's handler shuts the context down (spin ends, the node is destroyed) and then
        # calls Python's, which would raise KeyboardInterrupt wherever a callback is (a render inside numba)
        signal.signal(signal.SIGINT, lambda signum, frame: None)
    rclpy.init(args=args)
    try:
        node = node_class()
    except PegasusError as exc:  # parameters it refuses: one line and exit code 2, as the CLIs
        rclpy.try_shutdown()
        print(f"error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):  # Ctrl-C (rclpy's signal handler shuts the context down)
        pass
    except Exception:
        if rclpy.ok(context=node.context):
            raise
        # a callback that was running when Ctrl-C shut the context down (a publish into it fails): the end
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


__all__ = ["run_node", "finish", "declare", "TransformBroadcaster", "StaticTransformBroadcaster", "latched", "rclpy",
           "Node", "QoSProfile", "ReliabilityPolicy", "DurabilityPolicy", "MultiThreadedExecutor",
           "SingleThreadedExecutor", "Parameter", "msgs", "message_type", "serialize", "REAL_ROS"]

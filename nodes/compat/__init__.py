"""A stand-in for the subset of rclpy the nodes use, for machines without ROS 2 (``nodes.ros`` picks the real
rclpy when it imports): one module per rclpy module (exceptions, qos, expand_topic_name, context, task,
topics for publisher and subscription, timer, service for service and client, parameter, clock, node,
executors) and tf2 for tf2_ros's two broadcasters, with rclpy's names and call shapes, all of them here too
(``init/shutdown/ok``, ``Node``, QoS profiles, ``SingleThreadedExecutor`` / ``MultiThreadedExecutor``,
``spin``, ``spin_once``, ``spin_until_future_complete``, ``Future``).

Transport: in-process. A context holds the graph; ``publish`` puts the message on each matching
subscription's queue (``depth`` newest kept, as KEEP_LAST), and an executor runs the callbacks of the nodes
added to it: messages, due timers, service requests, client responses. Messages are passed by reference,
as rclpy's intra-process mode does, so subscribers must not change them. Nodes meant to talk across
processes need real ROS 2 (rclpy); launch files run every node in one process.
"""

from nodes.compat.clock import Clock, Time
from nodes.compat.context import Context, init, ok, shutdown, try_shutdown
from nodes.compat.exceptions import (
    ExternalShutdownException,
    InvalidParameterTypeException,
    InvalidTopicNameException,
    ParameterAlreadyDeclaredException,
    ParameterException,
    ParameterNotDeclaredException,
    ParameterUninitializedException,
    RCLError,
)
from nodes.compat.executors import (
    MultiThreadedExecutor,
    SingleThreadedExecutor,
    spin,
    spin_once,
    spin_until_future_complete,
)
from nodes.compat.expand_topic_name import expand_topic_name
from nodes.compat.node import Node, create_node
from nodes.compat.parameter import Parameter, ParameterDescriptor, ParameterValue, SetParametersResult
from nodes.compat.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    incompatible_policy,
    qos_profile_sensor_data,
    qos_profile_system_default,
)
from nodes.compat.service import Client, Service
from nodes.compat.task import Future
from nodes.compat.tf2 import StaticTransformBroadcaster, TransformBroadcaster
from nodes.compat.timer import Timer
from nodes.compat.topics import Publisher, Subscription, TopicEndpointInfo, matched

__all__ = [
    'Client', 'Clock', 'Context', 'DurabilityPolicy', 'ExternalShutdownException', 'Future', 'HistoryPolicy',
    'InvalidParameterTypeException', 'InvalidTopicNameException', 'MultiThreadedExecutor', 'Node',
    'Parameter', 'ParameterAlreadyDeclaredException', 'ParameterDescriptor', 'ParameterException',
    'ParameterNotDeclaredException', 'ParameterUninitializedException', 'ParameterValue', 'Publisher',
    'QoSProfile', 'RCLError', 'ReliabilityPolicy', 'Service', 'SetParametersResult', 'SingleThreadedExecutor',
    'StaticTransformBroadcaster', 'Subscription', 'Time', 'Timer', 'TopicEndpointInfo',
    'TransformBroadcaster', 'create_node', 'expand_topic_name', 'incompatible_policy', 'init', 'matched',
    'ok', 'qos_profile_sensor_data', 'qos_profile_system_default', 'shutdown', 'spin', 'spin_once',
    'spin_until_future_complete', 'try_shutdown',
]

"""A stand-in for the subset of rclpy the nodes use, for machines without ROS 2 (``nodes.ros`` picks the real
rclpy when it imports). Same names and call shapes as rclpy: ``init/shutdown/ok``, ``Node`` (publishers,
subscriptions, timers, services and clients, declared parameters, logger, clock), QoS profiles,
``SingleThreadedExecutor`` / ``MultiThreadedExecutor``, ``spin``, ``spin_once``,
``spin_until_future_complete``, ``Future``; and tf2_ros's two broadcasters.

Transport: in-process. A context holds the graph; ``publish`` puts the message on each matching
subscription's queue (``depth`` newest kept, as KEEP_LAST), and an executor runs the callbacks of the nodes
added to it: messages, due timers, service requests, client responses. Messages are passed by reference,
as rclpy's intra-process mode does, so subscribers must not change them. Nodes meant to talk across
processes need real ROS 2 (rclpy); launch files run every node in one process.
"""

from __future__ import annotations

import array
import collections
import concurrent.futures
import logging
import re
import threading
import time
import warnings
from dataclasses import dataclass
from enum import Enum, IntEnum

from nodes.msgs import TFMessage


class RCLError(RuntimeError):
    """rclpy._rclpy_pybind11.RCLError: what rcl refuses (a negative timer period, a second type on a topic)."""


class ExternalShutdownException(Exception):
    """rclpy.executors.ExternalShutdownException: real rclpy's spin raises it when a signal shut the context
    down; the stand-in's spin just returns."""


class ParameterException(Exception):
    """rclpy.exceptions.ParameterException: the message, then ``: `` and the parameter(s)."""

    def __init__(self, message: str, name):
        super().__init__(f"{message}: {name}")
        self.parameter_name = name


class ParameterNotDeclaredException(ParameterException):
    def __init__(self, name):
        super().__init__("Invalid access to undeclared parameter(s)", name)


class ParameterAlreadyDeclaredException(ParameterException):
    def __init__(self, name):
        super().__init__("Parameter(s) already declared", name)


class InvalidParameterTypeException(ParameterException):
    """A value of another type than the parameter's static type (rclpy.exceptions)."""

    def __init__(self, desired_parameter: "Parameter", expected_type: str):
        value = desired_parameter.value
        super().__init__(f"Trying to set parameter '{desired_parameter.name}' to '{value}' of type "
                         f"'{Parameter.Type.from_parameter_value(value).name}', expecting type '{expected_type}'",
                         desired_parameter.name)


class ParameterUninitializedException(ParameterException):
    def __init__(self, name: str):
        super().__init__(f"The parameter '{name}' is not initialized", name)


# -- QoS --------------------------------------------------------------------------------------------------
class HistoryPolicy(Enum):
    KEEP_LAST = 1
    KEEP_ALL = 2


class ReliabilityPolicy(Enum):
    RELIABLE = 1
    BEST_EFFORT = 2


class DurabilityPolicy(Enum):
    VOLATILE = 2
    TRANSIENT_LOCAL = 1


@dataclass
class QoSProfile:
    depth: int = 10
    history: HistoryPolicy = HistoryPolicy.KEEP_LAST
    reliability: ReliabilityPolicy = ReliabilityPolicy.RELIABLE
    durability: DurabilityPolicy = DurabilityPolicy.VOLATILE


qos_profile_sensor_data = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
qos_profile_system_default = QoSProfile()


def _qos(qos) -> QoSProfile:
    return QoSProfile(depth=qos) if isinstance(qos, int) else qos


def incompatible_policy(offered: QoSProfile, requested: QoSProfile) -> str | None:
    """The policy that keeps a publisher offering ``offered`` from a subscription requesting ``requested``
    (DDS's request-offered rules, as ROS 2 applies them), None when they match."""
    if offered.reliability == ReliabilityPolicy.BEST_EFFORT and requested.reliability == ReliabilityPolicy.RELIABLE:
        return "RELIABILITY"
    if offered.durability == DurabilityPolicy.VOLATILE and requested.durability == DurabilityPolicy.TRANSIENT_LOCAL:
        return "DURABILITY"
    return None


# -- names ------------------------------------------------------------------------------------------------
class InvalidTopicNameException(Exception):
    """rclpy.exceptions.InvalidTopicNameException"""


_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"


def expand_topic_name(name: str, node_name: str, namespace: str) -> str:
    """The fully qualified name of topic or service ``name`` as ROS 2 (rcl) expands it: relative names go
    under the node's namespace, ``~`` is the node's own, ``{node}`` / ``{ns}`` / ``{namespace}`` are
    substituted (another substitution is a ValueError); InvalidTopicNameException when it breaks ROS 2's name
    rules (tokens of letters, digits and underscores not starting with a digit, no empty token, no trailing
    ``/``, ``~`` only first and followed by ``/``)."""
    base = "/" + namespace.strip("/") if namespace.strip("/") else ""
    for sub in re.findall(r"\{[^{}]*\}", name):
        if sub not in ("{node}", "{ns}", "{namespace}"):
            raise ValueError(f"topic name {name!r} is invalid: unknown substitution: {sub}")
    expanded = name.replace("{node}", node_name).replace("{ns}", base or "/").replace("{namespace}", base or "/")
    if expanded == "~" or expanded.startswith("~/"):
        full = f"{base}/{node_name}{expanded[1:]}"
    else:
        full = expanded if expanded.startswith("/") else f"{base}/{expanded}"
    if not re.fullmatch(f"(/{_TOKEN})+", full):
        raise InvalidTopicNameException(f"Invalid topic name: {name!r} (expanded: {full!r}) breaks ROS 2's rules")
    return full


# -- context ----------------------------------------------------------------------------------------------
class Context:
    """The graph of one init(): topics -> subscriptions, services by name, latched messages. A context made
    with ``graph=`` another shares that one's graph but is shut down on its own: the nodes of one launch each
    get one, as each runs in a process of its own under ROS 2, and a node that shuts its context down
    (``try_shutdown``) ends alone."""

    def __init__(self, graph: "Context | None" = None):
        if graph is None:
            self.lock = threading.RLock()
            self.subscriptions: dict[str, list[Subscription]] = collections.defaultdict(list)
            self.publishers: dict[str, list[Publisher]] = collections.defaultdict(list)
            self.services: dict[str, Service] = {}
            # topic -> {publisher: its last message}, for TRANSIENT_LOCAL publishers (each keeps its own, as a
            # DDS writer does)
            self.latched: dict[str, dict] = collections.defaultdict(dict)
            self.wake = threading.Condition(self.lock)
        else:
            self.lock, self.subscriptions, self.services = graph.lock, graph.subscriptions, graph.services
            self.publishers = graph.publishers
            self.latched, self.wake = graph.latched, graph.wake
        self.owns_graph = graph is None
        self.running = False

    def notify(self) -> None:
        with self.wake:
            self.wake.notify_all()


_default = Context()


def init(args=None, context: Context | None = None, domain_id: int | None = None) -> None:
    """Start ``context`` (the default one); ``domain_id`` is accepted as rclpy's (every message stays in-process
    here: no other process is ever met)."""
    (context or _default).running = True


def ok(context: Context | None = None) -> bool:
    return (context or _default).running


def shutdown(context: Context | None = None) -> None:
    ctx = context or _default
    ctx.running = False
    ctx.notify()
    if ctx.owns_graph:
        with ctx.lock:
            ctx.subscriptions.clear()
            ctx.publishers.clear()
            ctx.services.clear()
            ctx.latched.clear()


def try_shutdown(context: Context | None = None) -> None:
    """Shut the context down unless it already is (rclpy.try_shutdown)."""
    if ok(context):
        shutdown(context)


def create_node(name: str, **kwargs) -> "Node":
    return Node(name, **kwargs)


# -- futures ----------------------------------------------------------------------------------------------
class Future:
    """rclpy.task.Future: result(), done(), set_result(), add_done_callback()."""

    def __init__(self):
        self._done, self._result, self._callbacks = threading.Event(), None, []

    def done(self) -> bool:
        return self._done.is_set()

    def result(self):
        return self._result

    def set_result(self, result) -> None:
        self._result = result
        self._done.set()
        for cb in self._callbacks:
            cb(self)

    def add_done_callback(self, callback) -> None:
        if self.done():
            callback(self)
        else:
            self._callbacks.append(callback)


# -- entities ---------------------------------------------------------------------------------------------
class Publisher:
    def __init__(self, node: "Node", msg_type, topic: str, qos: QoSProfile):
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


def _warn_unmatched(pub: Publisher, sub: "Subscription") -> None:
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


def _check_one_type(context: "Context", entity) -> None:
    """RCLError, as Fast DDS's one participant per context gives, when ``entity``'s topic already has an
    endpoint of another type in the same context (in separate contexts, as in separate processes, they only
    do not match)."""
    for table in (context.publishers, context.subscriptions):
        for other in table.get(entity.topic_name, []):
            if other.node.context is entity.node.context and other.msg_type is not entity.msg_type:
                raise RCLError(f"create_{type(entity).__name__.lower()}() called for existing topic name "
                               f"{entity.topic_name} with incompatible type {entity.msg_type.TYPE_NAME}")


class Subscription:
    def __init__(self, node: "Node", msg_type, topic: str, callback, qos: QoSProfile):
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


class Timer:
    def __init__(self, node: "Node", period: float, callback):
        if period < 0:
            raise RCLError("failed to create timer: timer period must be non-negative")
        self.node, self.period, self.callback = node, period, callback
        self.next_call = time.monotonic() + period
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True

    def reset(self) -> None:
        self.cancelled = False
        self.next_call = time.monotonic() + self.period

    def is_ready(self) -> bool:
        return not self.cancelled and time.monotonic() >= self.next_call

    def destroy(self) -> None:
        self.cancel()
        self.node.timers.remove(self)


class Service:
    def __init__(self, node: "Node", srv_type, name: str, callback):
        self.node, self.srv_type, self.name, self.callback = node, srv_type, name, callback
        self.requests: collections.deque = collections.deque()


class Client:
    def __init__(self, node: "Node", srv_type, name: str):
        self.node, self.srv_type, self.name = node, srv_type, name
        self.responses: collections.deque = collections.deque()  # (future, response) ready for callbacks

    def service_is_ready(self) -> bool:
        return self.name in self.node.context.services

    def wait_for_service(self, timeout_sec: float | None = None) -> bool:
        t0 = time.monotonic()
        while not self.service_is_ready():
            if timeout_sec is not None and time.monotonic() - t0 > timeout_sec:
                return False
            time.sleep(0.01)
        return True

    def call_async(self, request) -> Future:
        ctx = self.node.context
        with ctx.lock:
            service = ctx.services.get(self.name)
            if service is None:
                raise RuntimeError(f"service {self.name} is not available")
            future = Future()
            service.requests.append((request, future, self))
        ctx.notify()
        return future


class Parameter:
    """rclpy.parameter.Parameter: a name, a type (``Parameter.Type``, from the value unless given) and a value
    of that type (an int is not a DOUBLE; arrays are lists or tuples of one element type; an empty list is
    a BYTE_ARRAY)."""

    class Type(IntEnum):
        NOT_SET = 0
        BOOL = 1
        INTEGER = 2
        DOUBLE = 3
        STRING = 4
        BYTE_ARRAY = 5
        BOOL_ARRAY = 6
        INTEGER_ARRAY = 7
        DOUBLE_ARRAY = 8
        STRING_ARRAY = 9

        @classmethod
        def from_parameter_value(cls, value) -> "Parameter.Type":
            """The first type, in rclpy's order (bool before int; an empty list is a BYTE_ARRAY), that holds
            ``value``; TypeError when none does."""
            if value is None:
                return cls.NOT_SET
            kinds = _ARRAY_ITEMS if isinstance(value, (list, tuple, array.array)) else _SCALARS
            kind = next((kind for kind in kinds if cls(kind).check(value)), None)
            if kind is None:
                raise TypeError(f"The given value is not one of the allowed types '{value}'.")
            return cls(kind)

        def check(self, value) -> bool:
            """Whether ``value`` can be held as this type (rclpy's rule: a bool is an int here)."""
            if self == Parameter.Type.NOT_SET:
                return value is None
            if self in _SCALARS:
                return isinstance(value, _SCALARS[self])
            return isinstance(value, (list, tuple, array.array)) and all(isinstance(v, _ARRAY_ITEMS[self])
                                                                         for v in value)

    def __init__(self, name: str, type_: "Parameter.Type | None" = None, value=None):
        if type_ is None:
            type_ = Parameter.Type.from_parameter_value(value)
        if not isinstance(type_, Parameter.Type):
            raise TypeError(f"type_ must be a Parameter.Type, got {type_!r}")
        if not type_.check(value):
            raise ValueError(f"Type {type_} and value {value} do not agree")
        self._name, self._type, self._value = name, type_, value

    @property
    def name(self) -> str:
        return self._name

    @property
    def value(self):
        return self._value

    @property
    def type_(self) -> "Parameter.Type":
        return self._type

    def get_parameter_value(self) -> "ParameterValue":
        return ParameterValue.of(self._type, self._value)


# Parameter.Type -> the Python type of the value (of each item, for arrays), in rclpy's order of inference
_SCALARS = {Parameter.Type.BOOL: bool, Parameter.Type.INTEGER: int, Parameter.Type.DOUBLE: float,
            Parameter.Type.STRING: str}
_ARRAY_ITEMS = {Parameter.Type.BYTE_ARRAY: bytes, Parameter.Type.BOOL_ARRAY: bool, Parameter.Type.INTEGER_ARRAY: int,
                Parameter.Type.DOUBLE_ARRAY: float, Parameter.Type.STRING_ARRAY: str}


@dataclass
class ParameterValue:
    """rcl_interfaces.msg.ParameterValue: the field of the value's type is set, the others keep defaults."""

    type: int = 0
    bool_value: bool = False
    integer_value: int = 0
    double_value: float = 0.0
    string_value: str = ""
    byte_array_value: tuple = ()
    bool_array_value: tuple = ()
    integer_array_value: tuple = ()
    double_array_value: tuple = ()
    string_array_value: tuple = ()

    @classmethod
    def of(cls, type_: Parameter.Type, value) -> "ParameterValue":
        if type_ == Parameter.Type.NOT_SET:
            return cls()
        return cls(**{"type": int(type_), f"{type_.name.lower()}_value": value})


@dataclass
class SetParametersResult:
    """rcl_interfaces.msg.SetParametersResult"""

    successful: bool = False
    reason: str = ""


@dataclass
class ParameterDescriptor:
    """rcl_interfaces.msg.ParameterDescriptor, the fields the stand-in honours."""

    name: str = ""
    type: int = 0
    description: str = ""
    read_only: bool = False
    dynamic_typing: bool = False


class Clock:
    def now(self) -> "Time":
        return Time(nanoseconds=time.time_ns())


@dataclass
class Time:
    nanoseconds: int = 0

    def to_msg(self):
        from nodes.msgs import Time as TimeMsg

        return TimeMsg(sec=self.nanoseconds // 1_000_000_000, nanosec=self.nanoseconds % 1_000_000_000)


class Node:
    """rclpy.node.Node. ``parameter_overrides``: [Parameter] applied to declarations (how launch files
    pass parameters)."""

    def __init__(self, node_name: str, *, context: Context | None = None, parameter_overrides=None,
                 namespace: str = ""):
        self.context = context or _default
        self._name, self.namespace = node_name, namespace
        self.publishers, self.subscriptions, self.timers = [], [], []
        self.services, self.clients = [], []
        self._parameters: dict[str, Parameter] = {}
        self._descriptors: dict[str, ParameterDescriptor] = {}
        self._overrides = {p.name: p for p in (parameter_overrides or [])}
        self._logger = logging.getLogger(node_name)
        self._clock = Clock()

    def get_name(self) -> str:
        return self._name

    def get_logger(self) -> logging.Logger:
        return self._logger

    def get_clock(self) -> Clock:
        return self._clock

    def resolve_topic_name(self, topic: str) -> str:
        return expand_topic_name(topic, self._name, self.namespace)

    def create_publisher(self, msg_type, topic: str, qos_profile) -> Publisher:
        pub = Publisher(self, msg_type, self.resolve_topic_name(topic), _qos(qos_profile))
        pub.topic = topic
        with self.context.lock:
            _check_one_type(self.context, pub)
            self.context.publishers[pub.topic_name].append(pub)
            for sub in self.context.subscriptions.get(pub.topic_name, []):
                _warn_unmatched(pub, sub)
        self.publishers.append(pub)
        return pub

    def create_subscription(self, msg_type, topic: str, callback, qos_profile) -> Subscription:
        sub = Subscription(self, msg_type, self.resolve_topic_name(topic), callback, _qos(qos_profile))
        sub.topic = topic
        with self.context.lock:
            _check_one_type(self.context, sub)
            self.context.subscriptions[sub.topic_name].append(sub)
            for pub in self.context.publishers.get(sub.topic_name, []):
                _warn_unmatched(pub, sub)
        self.subscriptions.append(sub)
        return sub

    def get_topic_names_and_types(self) -> list[tuple[str, list[str]]]:
        """[(fully qualified topic, ["pkg/msg/Type", ...])] of every publisher and subscription in the graph,
        sorted by name, as rclpy gives it."""
        with self.context.lock:
            types = collections.defaultdict(set)
            for table in (self.context.publishers, self.context.subscriptions):
                for topic, entities in table.items():
                    types[topic].update(entity.msg_type.TYPE_NAME for entity in entities)
        return [(topic, sorted(names)) for topic, names in sorted(types.items()) if names]

    def get_publishers_info_by_topic(self, topic_name: str) -> list["TopicEndpointInfo"]:
        """What each publisher on ``topic_name`` offers (its node, type and QoS), as rclpy gives it."""
        with self.context.lock:
            publishers = list(self.context.publishers.get(self.resolve_topic_name(topic_name), []))
        return [TopicEndpointInfo(pub.node.get_name(), pub.node.namespace or "/", pub.msg_type.TYPE_NAME, pub.qos)
                for pub in publishers]

    def create_timer(self, timer_period_sec: float, callback) -> Timer:
        timer = Timer(self, timer_period_sec, callback)
        self.timers.append(timer)
        return timer

    def create_service(self, srv_type, srv_name: str, callback) -> Service:
        srv_name = self.resolve_topic_name(srv_name)
        with self.context.lock:
            if srv_name in self.context.services:
                raise RuntimeError(f"service {srv_name} already exists")
            service = Service(self, srv_type, srv_name, callback)
            self.context.services[srv_name] = service
        self.services.append(service)
        return service

    def create_client(self, srv_type, srv_name: str) -> Client:
        client = Client(self, srv_type, self.resolve_topic_name(srv_name))
        self.clients.append(client)
        return client

    def declare_parameter(self, name: str, value=None, descriptor: ParameterDescriptor | None = None,
                          ignore_override: bool = False) -> Parameter:
        """As rclpy: the type is static, from ``value`` (a default) or given as a ``Parameter.Type``; an override
        (or a later set) of another type raises InvalidParameterTypeException. Without either the parameter
        is dynamically typed (deprecated in rclpy, with a warning)."""
        if name in self._parameters:
            raise ParameterAlreadyDeclaredException(name)
        descriptor = ParameterDescriptor(name=name) if descriptor is None else descriptor
        if isinstance(value, Parameter.Type):
            if value == Parameter.Type.NOT_SET:
                raise ValueError(f"Cannot declare parameter {{{name}}} as statically typed of type NOT_SET")
            descriptor.type, value = int(value), None
        elif value is None and not descriptor.dynamic_typing:
            warnings.warn(f"when declaring parameter named '{name}', declaring a parameter only providing its name "
                          "is deprecated", stacklevel=2)
            descriptor.dynamic_typing = True
        elif not descriptor.dynamic_typing:
            descriptor.type = int(Parameter.Type.from_parameter_value(value))
        if not ignore_override and name in self._overrides:
            value = self._overrides[name].value
        param = Parameter(name, value=value)  # NOT_SET until given when declared by type alone
        self._check_type(param, descriptor)
        self._parameters[name], self._descriptors[name] = param, descriptor
        return param

    @staticmethod
    def _check_type(param: Parameter, descriptor: ParameterDescriptor) -> None:
        if (not descriptor.dynamic_typing and param.type_ != Parameter.Type.NOT_SET
                and param.type_ != descriptor.type):
            raise InvalidParameterTypeException(param, Parameter.Type(descriptor.type).name)

    def get_parameter(self, name: str) -> Parameter:
        if name not in self._parameters:
            raise ParameterNotDeclaredException(name)
        param = self._parameters[name]
        if param.type_ == Parameter.Type.NOT_SET and not self._descriptors[name].dynamic_typing:
            raise ParameterUninitializedException(name)
        return param

    def set_parameters(self, parameters: list[Parameter]) -> list["SetParametersResult"]:
        """As rclpy: an undeclared parameter raises ParameterNotDeclaredException (before any is set); a
        read-only one or one of another type than its static type is not set, and its result says why
        (``successful=False``, rclpy's reason)."""
        undeclared = [param.name for param in parameters if param.name not in self._parameters]
        if undeclared:
            raise ParameterNotDeclaredException(undeclared)
        results = []
        for param in parameters:
            descriptor = self._descriptors[param.name]
            if descriptor.read_only:
                results.append(SetParametersResult(False, f"Trying to set a read-only parameter: {param.name}."))
            elif (not descriptor.dynamic_typing and param.type_ != Parameter.Type.NOT_SET
                  and param.type_ != descriptor.type):
                expected = Parameter.Type(descriptor.type).name
                results.append(SetParametersResult(
                    False, f"Wrong parameter type, expected 'Type.{expected}' got 'Type.{param.type_.name}'"))
            else:
                self._parameters[param.name] = param
                results.append(SetParametersResult(True))
        return results

    def has_parameter(self, name: str) -> bool:
        return name in self._parameters

    def destroy_node(self) -> None:
        with self.context.lock:
            for sub in self.subscriptions:
                if sub in self.context.subscriptions[sub.topic_name]:  # gone already when the graph was shut down
                    self.context.subscriptions[sub.topic_name].remove(sub)
            for service in self.services:
                if self.context.services.get(service.name) is service:
                    del self.context.services[service.name]
            for pub in self.publishers:
                self.context.latched.get(pub.topic_name, {}).pop(pub, None)
                if pub in self.context.publishers[pub.topic_name]:
                    self.context.publishers[pub.topic_name].remove(pub)
        self.publishers, self.subscriptions, self.timers = [], [], []

    # work the executor can do now: [(callable, args)]
    def _ready_work(self) -> list:
        work = []
        for sub in self.subscriptions:
            if sub.queue:
                work.append((sub.callback, (sub.queue.popleft(),)))
        for timer in self.timers:
            if timer.is_ready():
                timer.next_call += timer.period
                if timer.next_call < time.monotonic():  # fell behind: no burst of catch-up calls
                    timer.next_call = time.monotonic() + timer.period
                work.append((timer.callback, ()))
        for service in self.services:
            while service.requests:
                request, future, client = service.requests.popleft()
                work.append((_serve, (service, request, future, client)))
        for client in self.clients:
            while client.responses:
                future, response = client.responses.popleft()
                work.append((future.set_result, (response,)))
        return work

    def _next_deadline(self) -> float | None:
        due = [t.next_call for t in self.timers if not t.cancelled]
        return min(due) if due else None


def _serve(service: Service, request, future: Future, client: Client) -> None:
    response = service.callback(request, service.srv_type.Response())
    with client.node.context.lock:
        client.responses.append((future, response))
    client.node.context.notify()


# -- tf2_ros broadcasters ---------------------------------------------------------------------------------
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


# -- executors --------------------------------------------------------------------------------------------
class SingleThreadedExecutor:
    """Runs the callbacks of its nodes one at a time in the spinning thread."""

    def __init__(self, context: Context | None = None):
        self.context = context or _default
        self.nodes: list[Node] = []

    def add_node(self, node: Node) -> bool:
        if node not in self.nodes:
            self.nodes.append(node)
        return True

    def remove_node(self, node: Node) -> None:
        self.nodes.remove(node)

    def _collect(self) -> list:
        """Ready work of the nodes whose context is still up (a node that shut its own down does no more)."""
        with self.context.lock:
            return [w for node in self.nodes if node.context.running for w in node._ready_work()]

    def _wait(self, timeout: float | None) -> None:
        deadlines = [d for d in (n._next_deadline() for n in self.nodes) if d is not None]
        wait = max(0.0, min(deadlines) - time.monotonic()) if deadlines else None
        if timeout is not None:
            wait = timeout if wait is None else min(wait, timeout)
        with self.context.wake:
            self.context.wake.wait(0.1 if wait is None else min(wait, 0.1))

    def _run(self, work: list) -> None:
        for callback, args in work:
            callback(*args)

    def spin_once(self, timeout_sec: float | None = None) -> None:
        work = self._collect()
        if not work:
            self._wait(timeout_sec)
            work = self._collect()
        self._run(work)

    def spin(self) -> None:
        while self.context.running:
            self.spin_once(0.1)

    def spin_until_future_complete(self, future: Future, timeout_sec: float | None = None) -> None:
        t0 = time.monotonic()
        while self.context.running and not future.done():
            if timeout_sec is not None and time.monotonic() - t0 > timeout_sec:
                return
            self.spin_once(0.05)

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        return True


class MultiThreadedExecutor(SingleThreadedExecutor):
    """Runs the ready callbacks on a thread pool (``num_threads``) and waits for them each round."""

    def __init__(self, num_threads: int | None = None, context: Context | None = None):
        super().__init__(context)
        self.pool = concurrent.futures.ThreadPoolExecutor(max_workers=num_threads or 4)

    def _run(self, work: list) -> None:
        for f in [self.pool.submit(callback, *args) for callback, args in work]:
            f.result()

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        self.pool.shutdown(wait=True)
        return True


def spin_once(node: Node, *, executor=None, timeout_sec: float | None = None) -> None:
    executor = executor or SingleThreadedExecutor(node.context)
    executor.add_node(node)
    executor.spin_once(timeout_sec)


def spin(node: Node, executor=None) -> None:
    executor = executor or SingleThreadedExecutor(node.context)
    executor.add_node(node)
    executor.spin()


def spin_until_future_complete(node: Node, future: Future, executor=None, timeout_sec: float | None = None) -> None:
    executor = executor or SingleThreadedExecutor(node.context)
    executor.add_node(node)
    executor.spin_until_future_complete(future, timeout_sec)

"""rclpy.node: a node (publishers, subscriptions, timers, services and clients, declared parameters, logger, clock)."""

from __future__ import annotations

import collections
import logging
import time
import warnings

from nodes.compat.clock import Clock
from nodes.compat.context import Context, default_context
from nodes.compat.exceptions import (
    InvalidParameterTypeException,
    ParameterAlreadyDeclaredException,
    ParameterNotDeclaredException,
    ParameterUninitializedException,
)
from nodes.compat.expand_topic_name import expand_topic_name
from nodes.compat.parameter import Parameter, ParameterDescriptor, SetParametersResult
from nodes.compat.qos import as_qos_profile
from nodes.compat.service import Client, Service, serve_request
from nodes.compat.timer import Timer
from nodes.compat.topics import Publisher, Subscription, TopicEndpointInfo, check_one_type, warn_unmatched


class Node:
    """rclpy.node.Node. ``parameter_overrides``: [Parameter] applied to declarations (how launch files
    pass parameters)."""

    def __init__(self, node_name: str, *, context: Context | None = None, parameter_overrides=None,
                 namespace: str = ""):
        self.context = context or default_context
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
        pub = Publisher(self, msg_type, self.resolve_topic_name(topic), as_qos_profile(qos_profile))
        pub.topic = topic
        with self.context.lock:
            check_one_type(self.context, pub)
            self.context.publishers[pub.topic_name].append(pub)
            for sub in self.context.subscriptions.get(pub.topic_name, []):
                warn_unmatched(pub, sub)
        self.publishers.append(pub)
        return pub

    def create_subscription(self, msg_type, topic: str, callback, qos_profile) -> Subscription:
        sub = Subscription(self, msg_type, self.resolve_topic_name(topic), callback, as_qos_profile(qos_profile))
        sub.topic = topic
        with self.context.lock:
            check_one_type(self.context, sub)
            self.context.subscriptions[sub.topic_name].append(sub)
            for pub in self.context.publishers.get(sub.topic_name, []):
                warn_unmatched(pub, sub)
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
                work.append((serve_request, (service, request, future, client)))
        for client in self.clients:
            while client.responses:
                future, response = client.responses.popleft()
                work.append((future.set_result, (response,)))
        return work

    def _next_deadline(self) -> float | None:
        due = [t.next_call for t in self.timers if not t.cancelled]
        return min(due) if due else None


def create_node(name: str, **kwargs) -> Node:
    """rclpy.create_node."""
    return Node(name, **kwargs)

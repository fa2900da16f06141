"""rclpy.service and rclpy.client: request-response, served by the executor that spins the node."""

from __future__ import annotations

import collections
import time

from nodes.compat.task import Future


class Service:
    def __init__(self, node, srv_type, name: str, callback):
        self.node, self.srv_type, self.name, self.callback = node, srv_type, name, callback
        self.requests: collections.deque = collections.deque()


class Client:
    def __init__(self, node, srv_type, name: str):
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



def serve_request(service: Service, request, future: Future, client: Client) -> None:
    response = service.callback(request, service.srv_type.Response())
    with client.node.context.lock:
        client.responses.append((future, response))
    client.node.context.notify()

"""rclpy.executors: the executors that run the callbacks of their nodes, and spin / spin_once."""

from __future__ import annotations

import concurrent.futures
import time

from nodes.compat.context import Context, default_context
from nodes.compat.node import Node
from nodes.compat.task import Future


class SingleThreadedExecutor:
    """Runs the callbacks of its nodes one at a time in the spinning thread."""

    def __init__(self, context: Context | None = None):
        self.context = context or default_context
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

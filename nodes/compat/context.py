"""rclpy.context and rclpy.init/ok/shutdown: the in-process graph of one init()."""

from __future__ import annotations

import collections
import threading


class Context:
    """The graph of one init(): topics -> subscriptions, services by name, latched messages. A context made
    with ``graph=`` another shares that one's graph but is shut down on its own: the nodes of one launch each
    get one, as each runs in a process of its own under ROS 2, and a node that shuts its context down
    (``try_shutdown``) ends alone."""

    def __init__(self, graph: "Context | None" = None):
        if graph is None:
            self.lock = threading.RLock()
            self.subscriptions: dict[str, list] = collections.defaultdict(list)
            self.publishers: dict[str, list] = collections.defaultdict(list)
            self.services: dict[str, object] = {}
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


default_context = Context()


def init(args=None, context: Context | None = None, domain_id: int | None = None) -> None:
    """Start ``context`` (the default one); ``domain_id`` is accepted as rclpy's (every message stays in-process
    here: no other process is ever met)."""
    (context or default_context).running = True


def ok(context: Context | None = None) -> bool:
    return (context or default_context).running


def shutdown(context: Context | None = None) -> None:
    ctx = context or default_context
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

"""Long jobs (generation, training) run by a node on a thread, so its executor keeps serving callbacks."""

from __future__ import annotations

import threading
import traceback


class BackgroundJob:
    """Runs ``work()`` on a daemon thread; ``done``, ``result`` and ``error`` (message) afterwards."""

    def __init__(self, work):
        self.done, self.result, self.error = False, None, None
        self._thread = threading.Thread(target=self._run, args=(work,), daemon=True)
        self._thread.start()

    def _run(self, work) -> None:
        try:
            self.result = work()
        except Exception as exc:  # noqa: BLE001 - reported to the node, which publishes it
            self.error = f"{type(exc).__name__}: {exc}"
            traceback.print_exc()
        finally:
            self.done = True

    @property
    def state(self) -> str:
        return "failed" if self.error else "done" if self.done else "running"

    def announce(self, node, publisher, what: str) -> None:
        """Once the job has ended, once: publish its result (a path) as a String, or log its error and end the
        node (``nodes.ros.finish``)."""
        if not self.done or getattr(self, "_announced", False):
            return
        self._announced = True
        from nodes.ros import finish, msgs

        if self.error is None:
            publisher.publish(msgs.String(data=str(self.result)))
            node.get_logger().info(f"{node.get_name()}: {what} ready at {self.result}")
        else:
            node.get_logger().error(f"{node.get_name()}: {self.error}")
            finish(node)

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

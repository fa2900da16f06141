"""rclpy.task: futures."""

from __future__ import annotations

import threading


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

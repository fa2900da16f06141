"""rclpy.timer: periodic callbacks."""

from __future__ import annotations

import time

from nodes.compat.exceptions import RCLError


class Timer:
    def __init__(self, node, period: float, callback):
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

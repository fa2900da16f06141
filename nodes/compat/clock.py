"""rclpy.clock and rclpy.time: wall-clock time."""

from __future__ import annotations

import time
from dataclasses import dataclass


class Clock:
    def now(self) -> "Time":
        return Time(nanoseconds=time.time_ns())


@dataclass
class Time:
    nanoseconds: int = 0

    def to_msg(self):
        from nodes.msgs import Time as TimeMsg

        return TimeMsg(sec=self.nanoseconds // 1_000_000_000, nanosec=self.nanoseconds % 1_000_000_000)

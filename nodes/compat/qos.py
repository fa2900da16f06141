"""rclpy.qos: QoS profiles and the rule by which an offered profile meets a requested one."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum


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


def as_qos_profile(qos) -> QoSProfile:
    return QoSProfile(depth=qos) if isinstance(qos, int) else qos


def incompatible_policy(offered: QoSProfile, requested: QoSProfile) -> str | None:
    """The policy that keeps a publisher offering ``offered`` from a subscription requesting ``requested``
    (DDS's request-offered rules, as ROS 2 applies them), None when they match."""
    if offered.reliability == ReliabilityPolicy.BEST_EFFORT and requested.reliability == ReliabilityPolicy.RELIABLE:
        return "RELIABILITY"
    if offered.durability == DurabilityPolicy.VOLATILE and requested.durability == DurabilityPolicy.TRANSIENT_LOCAL:
        return "DURABILITY"
    return None

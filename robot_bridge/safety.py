"""The safety envelope every robot command is checked against before anything is sent.

Checks (base frame, metres): the TCP inside a workspace box, at least ``min_height`` above the table top
``table_z``, the tool's z axis within ``max_tilt_deg`` of straight down, speeds and accelerations within
limits. A linear move is safe when both ends are: the box and the height limit are convex, and the
directions within a cone narrower than a hemisphere are too, so the straight path and its SLERPed
orientation stay inside. A joint move's Cartesian path is curved, so it is checked at ``samples`` points
along the joint interpolation through the forward kinematics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pegasus_gen.errors import PegasusError
from robot_bridge.kinematics import fk, pose_to_matrix


class UnsafeCommand(PegasusError):
    """A command outside the safety envelope; nothing was sent."""


@dataclass
class SafetyEnvelope:
    x: tuple[float, float] = (-0.8, 0.8)  # m, base frame
    y: tuple[float, float] = (-0.8, 0.8)
    z: tuple[float, float] = (-0.2, 0.9)
    table_z: float = 0.0  # table top in the base frame, m
    min_height: float = 0.01  # m of the TCP above the table top
    max_tilt_deg: float = 60.0  # tool z axis from straight down (< 90)
    max_speed: float = 0.5  # m/s (moveL)
    max_acceleration: float = 1.5  # m/s^2
    max_joint_speed: float = 1.6  # rad/s (moveJ)
    max_joint_acceleration: float = 3.0  # rad/s^2
    samples: int = 50  # points checked along a joint move

    def __post_init__(self):
        if not 0 < self.max_tilt_deg < 90:
            raise PegasusError(f"max_tilt_deg must be within (0, 90), got {self.max_tilt_deg}")
        for name in ("x", "y", "z"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise PegasusError(f"safety box {name} must be (min, max) with min < max, got {(lo, hi)}")

    def problems(self, T_base_tcp: np.ndarray) -> list[str]:
        """What is wrong with a TCP pose [4, 4] (empty when it is inside the envelope)."""
        found = []
        p = T_base_tcp[:3, 3]
        for axis, value, (lo, hi) in zip("xyz", p, (self.x, self.y, self.z)):
            if not lo <= value <= hi:
                found.append(f"{axis} = {value:.3f} m is outside the workspace [{lo}, {hi}]")
        if p[2] < self.table_z + self.min_height:
            found.append(f"z = {p[2]:.3f} m is less than {self.min_height} m above the table top "
                         f"(z = {self.table_z} m)")
        tilt = np.degrees(np.arccos(np.clip(-T_base_tcp[2, 2], -1, 1)))
        if tilt > self.max_tilt_deg:
            found.append(f"the tool is tilted {tilt:.1f} deg from straight down (limit {self.max_tilt_deg})")
        return found

    def check_pose(self, pose, what: str = "target") -> None:
        """Raise UnsafeCommand naming every problem of ``pose`` ([x, y, z, rx, ry, rz] or [4, 4])."""
        T = np.asarray(pose, dtype=np.float64)
        T = T if T.shape == (4, 4) else pose_to_matrix(T)
        found = self.problems(T)
        if found:
            raise UnsafeCommand(f"{what} refused: " + "; ".join(found))

    def check_motion(self, speed: float, acceleration: float, joint: bool = False) -> None:
        """Raise UnsafeCommand for a non-positive or too high speed or acceleration (of the TCP, or of the
        joints with ``joint``)."""
        unit = "rad" if joint else "m"
        limits = (self.max_joint_speed, self.max_joint_acceleration) if joint else (self.max_speed,
                                                                                    self.max_acceleration)
        if not 0 < speed <= limits[0]:
            raise UnsafeCommand(f"speed {speed} {unit}/s refused: must be within (0, {limits[0]}]")
        if not 0 < acceleration <= limits[1]:
            raise UnsafeCommand(f"acceleration {acceleration} {unit}/s^2 refused: must be within (0, {limits[1]}]")

    def check_linear(self, T_start: np.ndarray, target, speed: float, acceleration: float) -> None:
        """A moveL from the TCP pose ``T_start`` [4, 4] to ``target``."""
        self.check_motion(speed, acceleration)
        self.check_pose(T_start, "moveL start")
        self.check_pose(target, "moveL target")

    def check_joint(self, q_start, q_target, speed: float, acceleration: float,
                    tcp: np.ndarray | None = None) -> None:
        """A moveJ from joints ``q_start`` [6] to ``q_target`` [6] (rad), TCP = flange @ ``tcp``."""
        self.check_motion(speed, acceleration, joint=True)
        q_start, q_target = np.asarray(q_start, float), np.asarray(q_target, float)
        for s in np.linspace(0.0, 1.0, self.samples):
            found = self.problems(fk(q_start + s * (q_target - q_start), tcp))
            if found:
                raise UnsafeCommand(f"moveJ refused at {s:.0%} of the way: " + "; ".join(found))

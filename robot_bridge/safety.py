"""The safety envelope every robot command is checked against before anything is sent.

Checks (base frame, metres): every number finite, a target matrix a rigid transform (the pose sent is the
one checked), the TCP inside a workspace box, at least ``min_height`` above the table top ``table_z``, the
tool's z axis within ``max_tilt_deg`` of straight down, speeds and accelerations within limits, joint targets
within the UR5's joint limits. A linear move's straight path stays in the box and above the table when its
ends do (both are convex), but its SLERPed orientation can tilt beyond the cone in the middle although both
ends lie inside (53.2 and 51.6 degree ends reach 75.8 degrees), so the path is checked at ``samples`` points
at least, one per half degree of rotation, with the controller's interpolation (straight line, SLERP). A
joint move's Cartesian path is curved, so it is checked at ``samples`` points along the joint interpolation
through the forward kinematics. The envelope's own parameters are checked when it is made: a NaN limit compares
false and would switch its check off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from pegasus_gen.errors import PegasusError
from robot_bridge.kinematics import (
    JOINT_LIMIT,
    fk,
    joints_problem,
    matrix_to_rtde_pose,
    rtde_pose_problem,
    rtde_pose_to_matrix,
)


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
    samples: int = 50  # points checked along a move at least (both ends among them)
    joint_limit: float = JOINT_LIMIT  # rad, each joint's |q|, at most the UR5's

    def __post_init__(self):
        """PegasusError for a parameter that would switch its check off or make no sense (NaN compares false,
        so a NaN limit would let everything through)."""
        for name in ("x", "y", "z"):
            lo, hi = getattr(self, name)
            if not (np.isfinite([lo, hi]).all() and lo < hi):
                raise PegasusError(f"safety box {name} must be finite (min, max) with min < max, got {(lo, hi)}")
        for name in ("table_z", "min_height"):
            if not np.isfinite(getattr(self, name)):
                raise PegasusError(f"safety envelope {name} must be a finite number (m), got {getattr(self, name)}")
        if not 0 < self.max_tilt_deg < 90:
            raise PegasusError(f"max_tilt_deg must be within (0, 90), got {self.max_tilt_deg}")
        for name in ("max_speed", "max_acceleration", "max_joint_speed", "max_joint_acceleration"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise PegasusError(f"safety envelope {name} must be finite and positive, got {getattr(self, name)}")
        if isinstance(self.samples, bool) or not isinstance(self.samples, (int, np.integer)) or self.samples < 2:
            raise PegasusError(f"safety envelope samples must be a whole number >= 2, got {self.samples!r}")
        if not 0 < self.joint_limit <= JOINT_LIMIT:
            raise PegasusError(f"safety envelope joint_limit must be within (0, {JOINT_LIMIT:.3f}] rad, got "
                               f"{self.joint_limit}")

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

    def sent_pose(self, pose, what: str = "target") -> np.ndarray:
        """T [4, 4] of the pose a command sends for ``pose`` ([x, y, z, rx, ry, rz], or [4, 4]: sent as its
        rotation vector): UnsafeCommand when a number is not finite, a rotation vector is absurdly long
        (``kinematics.rtde_pose_problem``) or a matrix is not a rigid transform (a scaled or sheared rotation
        would be sent as some nearby rotation that was never checked)."""
        T = np.asarray(pose, dtype=np.float64)
        if T.shape not in ((6,), (4, 4)):
            raise UnsafeCommand(f"{what} refused: a pose is [x, y, z, rx, ry, rz] or a 4x4 matrix, got shape "
                                f"{T.shape}")
        if T.shape == (6,):
            problem = rtde_pose_problem(T)
            if problem is not None:
                raise UnsafeCommand(f"{what} refused: {problem}")
            return rtde_pose_to_matrix(T)
        if not np.isfinite(T).all():
            raise UnsafeCommand(f"{what} refused: it holds a NaN or infinite number")
        R = T[:3, :3]
        if (np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or abs(np.linalg.det(R) - 1) > 1e-6
                or not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0])):
            raise UnsafeCommand(f"{what} refused: not a rigid transform (its rotation is scaled, sheared or "
                                "mirrored)")
        return rtde_pose_to_matrix(matrix_to_rtde_pose(T))

    def check_pose(self, pose, what: str = "target") -> np.ndarray:
        """The pose sent for ``pose`` (``sent_pose``) [4, 4]; UnsafeCommand naming every problem it has."""
        T = self.sent_pose(pose, what)
        found = self.problems(T)
        if found:
            raise UnsafeCommand(f"{what} refused: " + "; ".join(found))
        return T

    def check_motion(self, speed: float, acceleration: float, joint: bool = False) -> None:
        """Raise UnsafeCommand for a non-positive or too high speed or acceleration (of the TCP, or of the
        joints with ``joint``)."""
        unit = "rad" if joint else "m"
        limits = (self.max_joint_speed, self.max_joint_acceleration) if joint else (self.max_speed,
                                                                                    self.max_acceleration)
        if not (np.isfinite(speed) and 0 < speed <= limits[0]):
            raise UnsafeCommand(f"speed {speed} {unit}/s refused: must be within (0, {limits[0]}]")
        if not (np.isfinite(acceleration) and 0 < acceleration <= limits[1]):
            raise UnsafeCommand(f"acceleration {acceleration} {unit}/s^2 refused: must be within (0, {limits[1]}]")

    def check_linear(self, T_start: np.ndarray, target, speed: float, acceleration: float) -> np.ndarray:
        """A moveL from the TCP pose ``T_start`` [4, 4] to ``target``, the whole path: returns the target pose
        sent [4, 4]."""
        self.check_motion(speed, acceleration)
        T_start = self.check_pose(T_start, "moveL start")
        T_target = self.check_pose(target, "moveL target")
        rotations = Slerp([0, 1], Rotation.from_matrix([T_start[:3, :3], T_target[:3, :3]]))
        angle = np.degrees((rotations(1.0) * rotations(0.0).inv()).magnitude())
        for s in np.linspace(0.0, 1.0, max(self.samples, int(np.ceil(angle / 0.5)) + 1)):
            T = np.eye(4)
            T[:3, :3] = rotations(s).as_matrix()
            T[:3, 3] = T_start[:3, 3] + s * (T_target[:3, 3] - T_start[:3, 3])
            found = self.problems(T)
            if found:
                raise UnsafeCommand(f"moveL refused at {s:.0%} of the way: " + "; ".join(found))
        return T_target

    def check_joint(self, q_start, q_target, speed: float, acceleration: float,
                    tcp: np.ndarray | None = None) -> None:
        """A moveJ from joints ``q_start`` [6] to ``q_target`` [6] (rad), TCP = flange @ ``tcp``."""
        self.check_motion(speed, acceleration, joint=True)
        q_start, q_target = np.asarray(q_start, float), np.asarray(q_target, float)
        problem = joints_problem(q_target, self.joint_limit)
        if problem is not None:
            raise UnsafeCommand(f"moveJ refused: {problem}")
        for s in np.linspace(0.0, 1.0, self.samples):
            found = self.problems(fk(q_start + s * (q_target - q_start), tcp))
            if found:
                raise UnsafeCommand(f"moveJ refused at {s:.0%} of the way: " + "; ".join(found))

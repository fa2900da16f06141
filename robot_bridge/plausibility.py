"""Is a pose estimate plausible enough to move the robot for? Checked before any command is sent.

A wrong estimate (the object placed under the table, or far off because the estimator got its depth 1.4x
too large) would drive the arm into the scene: a protective stop in the simulated cell, a collision on a
real UR5. The safety envelope (``robot_bridge.safety``) only bounds the TCP; these checks bound what the
estimate claims about the world. Base frame, metres; ``PlausibilityParams`` holds the numbers:

- the pose is finite and its rotation is a rotation (orthonormal within 1e-3, determinant +1);
- the object's lowest point (its model box's lowest corner) is at most 2 cm below the table top: deeper
  would put it inside the table, and the grasp with it (tilted estimates sink their corners by a few mm);
- its lowest point is at most 3 cm above the table top: objects in the cell rest on the table, so one
  floating higher is a depth or scale error;
- its centre is 0.2-0.8 m horizontally from the base's z axis (a UR5 reaches 0.85 m; inside 0.2 m the
  wrist meets the base column) and inside the safety envelope's box;
- ``plan_problem``: at the grasp of the plan, the fingertips, 15 mm past the TCP (``robot_bridge.ur5_urdf``:
  the TCP sits between the fingertips, 15 mm above their ends), stay above the table top. ``plan_grasp``
  keeps the TCP ``finger_clearance`` (22 mm) above the table it is given, so this catches a plan made for
  another table height or with a smaller clearance.

Each check returns None when the estimate passes, else one short line saying why not.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pegasus_gen.geometry.cuboid import cuboid_points
from robot_bridge.grasp import GraspPlan
from robot_bridge.safety import SafetyEnvelope
from robot_bridge.ur5_urdf import FINGER, GRIPPER_BODY, TCP_Z

FINGERTIPS_BELOW_TCP = GRIPPER_BODY[2] + FINGER[2] - TCP_Z  # m (0.015): the fingertips' ends below the TCP


@dataclass
class PlausibilityParams:
    below_table: float = 0.02  # m: the object's lowest point may be this far below the table top
    above_table: float = 0.03  # m: ... and this far above it (it rests on the table)
    min_reach: float = 0.2  # m: the centre's horizontal distance from the base's z axis, at least
    max_reach: float = 0.8  # m: ... and at most (UR5: 0.85 m reach)
    fingertips_below_tcp: float = FINGERTIPS_BELOW_TCP  # m: how far the fingertips reach past the TCP
    rotation_tolerance: float = 1e-3  # |R^T R - I| and |det R - 1|, at most


def pose_problem(T_base_obj: np.ndarray, bbox_min, bbox_size, table_z: float = 0.0,
                 params: PlausibilityParams | None = None, envelope: SafetyEnvelope | None = None) -> str | None:
    """None when the object pose T_base_obj [4, 4] (m, base frame) is plausible for an object with the model
    box ``bbox_min``/``bbox_size`` [3] (m, object frame) on a table whose top is at z = ``table_z`` (m, base
    frame), else why not (see the module docstring). ``envelope``: whose box the centre must be in
    (default ``SafetyEnvelope()``)."""
    p = params or PlausibilityParams()
    envelope = envelope or SafetyEnvelope()
    T = np.asarray(T_base_obj, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        return "the pose is not a finite 4x4 matrix"
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > p.rotation_tolerance or abs(np.linalg.det(R) - 1) > p.rotation_tolerance:
        return "the pose's rotation is not a rotation matrix"
    points = cuboid_points(bbox_min, bbox_size) @ R.T + T[:3, 3]  # [9, 3]: 8 corners, centre
    low, centre = points[:8, 2].min() - table_z, points[8]
    if low < -p.below_table:
        return (f"the object's lowest point is {-low * 100:.1f} cm below the table top "
                f"(tolerance {p.below_table * 100:.0f} cm)")
    if low > p.above_table:
        return (f"the object's lowest point floats {low * 100:.1f} cm above the table top "
                f"(tolerance {p.above_table * 100:.0f} cm)")
    reach = float(np.hypot(centre[0], centre[1]))
    if not p.min_reach <= reach <= p.max_reach:
        return (f"the object's centre is {reach:.2f} m from the base axis: out of reach "
                f"([{p.min_reach}, {p.max_reach}] m)")
    for axis, value, (lo, hi) in zip("xyz", centre, (envelope.x, envelope.y, envelope.z)):
        if not lo <= value <= hi:
            return f"the object's centre {axis} = {value:.3f} m is outside the safety envelope [{lo}, {hi}]"
    return None


def plan_problem(plan: GraspPlan, table_z: float = 0.0, params: PlausibilityParams | None = None) -> str | None:
    """None when at the grasp of ``plan`` (``robot_bridge.grasp.plan_grasp``; its lowest waypoint over the
    object) the fingertips, which reach ``params.fingertips_below_tcp`` (m) past the TCP along the tool's z
    axis, stay above the table top at z = ``table_z`` (m, base frame); else why not. The place is not
    checked against the table: it is over the basket, whose floor may be elsewhere."""
    p = params or PlausibilityParams()
    T = plan.grasp
    tips = T[2, 3] + p.fingertips_below_tcp * T[2, 2]  # m: the fingertips' height, base frame
    if not np.isfinite(tips):
        return "the grasp is not finite"
    if tips < table_z:
        return (f"the fingertips would reach {(table_z - tips) * 100:.1f} cm into the table at the grasp "
                f"(TCP z = {T[2, 3]:.3f} m)")
    return None

"""Grasp and place waypoints for a parallel-jaw gripper from an object pose seen by a camera.

Frames: T_cam_obj from pose estimation (OpenCV camera frame), T_base_cam the hand-eye calibration (camera in
the robot base frame), so T_base_obj = T_base_cam @ T_cam_obj. The object is described by its model box
(min corner and size, metres, object frame) and an optional symmetry axis (``axis`` in the object frame;
a cup: z, continuous symmetry).

Rule: the tool always points straight down. The jaws close horizontally, across the object: for an object
standing on its symmetry axis, in whatever direction is nearest the tool's current yaw (symmetry makes all
equal); for one lying or leaning, square to the axis (across its diameter); without a symmetry axis,
across the narrower horizontal extent of the box; each turned by pi where that is nearer.
The TCP goes to ``grasp_height`` of the object's vertical extent above its lowest point (above the centre
of mass for upright cups, below their wide rim), never lower than ``finger_clearance`` above the table.
Waypoints: pre-grasp (``approach`` above the grasp), grasp, lift (``lift`` above the grasp), pre-place and
place (over the basket centre, the object's bottom ``drop_height`` above the basket floor), retreat.
Each is checked against the safety envelope; an opening wider than the gripper's stroke is refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pegasus_gen.geometry.cuboid import cuboid_points
from robot_bridge.safety import SafetyEnvelope, UnsafeCommand


@dataclass
class GraspParams:
    grasp_height: float = 0.6  # fraction of the object's vertical extent above its lowest point
    approach: float = 0.12  # m above the grasp for the pre-grasp
    lift: float = 0.18  # m
    drop_height: float = 0.03  # m above the basket floor for the object's lowest point
    finger_clearance: float = 0.022  # m: the TCP stays this far above the table (fingertips reach 15 mm past it)
    stroke: float = 0.14  # m: widest opening of the jaws
    min_margin: float = 0.01  # m: the jaws open at least this much wider than the object


@dataclass
class GraspPlan:
    """TCP poses T_base_tcp [4, 4]: pre_grasp, grasp, lift, pre_place, place, retreat; the object's width
    across the jaws (m)."""

    pre_grasp: np.ndarray
    grasp: np.ndarray
    lift: np.ndarray
    pre_place: np.ndarray
    place: np.ndarray
    retreat: np.ndarray
    width: float

    def waypoints(self) -> list[tuple[str, np.ndarray]]:
        return [(n, getattr(self, n)) for n in ("pre_grasp", "grasp", "lift", "pre_place", "place", "retreat")]


def _tool_down(yaw: float, position) -> np.ndarray:
    """TCP pose with z pointing down and the jaws' closing axis (tool y) at ``yaw`` in the base xy-plane."""
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, 1] = [c, s, 0.0]  # closing direction
    T[:3, 2] = [0.0, 0.0, -1.0]
    T[:3, 0] = np.cross(T[:3, 1], T[:3, 2])
    T[:3, 3] = position
    return T


def _nearest_yaw(candidates, current: float) -> float:
    return min(candidates, key=lambda a: abs((a - current + np.pi) % (2 * np.pi) - np.pi))


def plan_grasp(T_cam_obj: np.ndarray, T_base_cam: np.ndarray, bbox_min, bbox_size, basket_centre,
               basket_floor_z: float, current_tcp: np.ndarray, axis=None, table_z: float = 0.0,
               params: GraspParams | None = None, envelope: SafetyEnvelope | None = None) -> GraspPlan:
    """The waypoints (see the module docstring); raises UnsafeCommand when the grasp cannot be made safely."""
    p = params or GraspParams()
    T = T_base_cam @ T_cam_obj
    corners = cuboid_points(bbox_min, bbox_size)[:8] @ T[:3, :3].T + T[:3, 3]  # [8, 3] base frame
    low, high = corners[:, 2].min(), corners[:, 2].max()
    centre = (cuboid_points(bbox_min, bbox_size)[8] @ T[:3, :3].T + T[:3, 3])
    current_yaw = float(np.arctan2(current_tcp[1, 1], current_tcp[0, 1]))
    axis_base = None if axis is None else T[:3, :3] @ np.asarray(axis, float)
    if axis_base is not None and abs(axis_base[2]) > np.cos(np.radians(20)):
        yaw = current_yaw  # standing on its symmetry axis: every direction across it is alike
        radial = np.linalg.norm(corners[:, :2] - centre[:2], axis=1).max() / np.sqrt(2)
        width = 2 * radial
    elif axis_base is not None:  # lying or leaning: close horizontally, square to the axis
        across = np.array([-axis_base[1], axis_base[0]]) / np.linalg.norm(axis_base[:2])
        yaw = _nearest_yaw([np.arctan2(across[1], across[0]) + k * np.pi for k in (0, 1)], current_yaw)
        width = float(np.delete(np.asarray(bbox_size, float), int(np.argmax(np.abs(axis)))).max())  # diameter
    else:
        # across the narrower horizontal extent of the box
        extents = []
        for k in range(3):
            direction = T[:3, k].copy()
            direction[2] = 0.0
            if np.linalg.norm(direction) < 0.3:  # mostly vertical: not a closing direction
                continue
            direction /= np.linalg.norm(direction)
            extents.append((np.ptp(corners[:, :2] @ direction[:2]), float(np.arctan2(direction[1], direction[0]))))
        width, base_yaw = min(extents)
        yaw = _nearest_yaw([base_yaw, base_yaw + np.pi], current_yaw)
    if width + p.min_margin > p.stroke:
        raise UnsafeCommand(f"the object is {width * 100:.1f} cm across: wider than the gripper opens "
                            f"({p.stroke * 100:.0f} cm) with margin")
    z = max(low + p.grasp_height * (high - low), table_z + p.finger_clearance)
    grasp = _tool_down(yaw, [centre[0], centre[1], z])
    up = np.array([0.0, 0.0, 1.0])

    def moved(T_, dz):
        out = T_.copy()
        out[:3, 3] += dz * up
        return out

    place_z = basket_floor_z + p.drop_height + (z - low)
    place = _tool_down(yaw, [basket_centre[0], basket_centre[1], place_z])
    plan = GraspPlan(moved(grasp, p.approach), grasp, moved(grasp, p.lift), moved(place, p.lift), place,
                     moved(place, p.lift), float(width))
    if envelope is not None:
        for name, pose in plan.waypoints():
            envelope.check_pose(pose, what=f"grasp waypoint {name}")
    return plan

"""Pick and place with a UR5 and a parallel-jaw gripper: one checked attempt (the estimate and the plan
checked before anything is sent, then home and the pick), and the grasp plan's waypoints executed through the
bridge, with the grasp checked on the jaws' opening where the gripper reports it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from robot_bridge.attempts import IMPLAUSIBLE_DETAIL
from robot_bridge.bridge import UR5
from robot_bridge.cell import BASKET_CLEARANCE_M, CellLayout
from robot_bridge.grasp import GraspPlan, plan_grasp
from robot_bridge.kinematics import fk
from robot_bridge.plausibility import plan_problem, pose_problem


@dataclass
class PickResult:
    """held: the jaws stopped on something (None when the gripper does not report its opening);
    width: their opening after closing (m) or None; reason: why the pick was abandoned, else ''."""

    held: bool | None
    width: float | None
    reason: str = ""


@dataclass(frozen=True)
class PickTarget:
    """What the robot knows of the object: its model box (bbox_min, bbox_size [3], m, object frame) and the
    axis about which its shape is rotationally symmetric (object frame; None: none)."""

    bbox_min: tuple[float, float, float]
    bbox_size: tuple[float, float, float]
    symmetry_axis: tuple[float, float, float] | None = None


@dataclass
class AttemptOutcome:
    """result: picked, missed, pregrasp or implausible; detail: what happened (implausible: IMPLAUSIBLE_DETAIL
    and the reason; nothing was sent to the robot); plan: the grasp plan (None when refused before it)."""

    result: str
    detail: str
    plan: GraspPlan | None = None


def home_tcp(robot: UR5, home) -> np.ndarray:
    """T_base_tcp [4, 4] at the ``home`` joints (rad): the forward kinematics with the controller's TCP offset
    (T_flange_tcp, read from where the arm is now), without moving there."""
    T_flange_tcp = np.linalg.inv(fk(robot.joint_positions())) @ robot.tcp_pose()
    return fk(home, T_flange_tcp)


def attempt_pick(robot: UR5, T_cam_obj: np.ndarray, T_base_cam: np.ndarray, target: PickTarget, cell: CellLayout,
                 execute: str = "pick", connect: Callable[[], None] = lambda: None,
                 moving: Callable[[], None] = lambda: None) -> AttemptOutcome:
    """One pick attempt for the estimate T_cam_obj [4, 4] (m, camera frame) seen by a camera at T_base_cam
    [4, 4] in ``cell`` (basket, table height, home joints). Before anything is sent: the estimate's
    plausibility (``plausibility.pose_problem``), then ``connect()``, the grasp planned from the home joints'
    TCP (not moved there) and the plan checked (``plan_problem``); a refusal returns ``implausible``. Then
    ``moving()``, the arm home, and with ``execute`` = pick the whole pick-and-place (picked, or missed when
    the jaws closed on nothing), with pregrasp a stop above the object. The robot's errors (PegasusError)
    propagate."""
    envelope = robot.config.envelope
    reason = pose_problem(T_base_cam @ T_cam_obj, target.bbox_min, target.bbox_size, cell.table_z, envelope=envelope)
    if reason is not None:
        return AttemptOutcome("implausible", IMPLAUSIBLE_DETAIL + reason)
    connect()
    plan = plan_grasp(T_cam_obj, T_base_cam, target.bbox_min, target.bbox_size, cell.basket[:2],
                      cell.basket[2] + BASKET_CLEARANCE_M, home_tcp(robot, cell.home), axis=target.symmetry_axis,
                      table_z=cell.table_z, envelope=envelope)
    reason = plan_problem(plan, cell.table_z)
    if reason is not None:
        return AttemptOutcome("implausible", IMPLAUSIBLE_DETAIL + reason, plan)
    moving()
    robot.move_j(cell.home)
    if execute == "pregrasp":
        robot.move_l(plan.pre_grasp)
        return AttemptOutcome("pregrasp", "at the pre-grasp", plan)
    result = pick_and_place(robot, plan)
    return AttemptOutcome("picked" if result.held is not False else "missed", result.reason or "placed", plan)


def pick_and_place(robot: UR5, plan: GraspPlan, min_hold_width: float = 0.01) -> PickResult:
    """Open, approach, grasp, lift, carry to the basket, release, retreat. A missed grasp (jaws closed to
    less than ``min_hold_width``) opens the gripper, lifts back to the pre-grasp and stops there."""
    robot.gripper_open()
    robot.move_l(plan.pre_grasp)
    robot.move_l(plan.grasp)
    robot.gripper_close()
    width = robot.gripper_width()
    if width is not None and width < min_hold_width:
        robot.gripper_open()
        robot.move_l(plan.pre_grasp)
        return PickResult(False, width, f"nothing between the jaws (opening {width * 1000:.0f} mm)")
    robot.move_l(plan.lift)
    robot.move_l(plan.pre_place)
    robot.move_l(plan.place)
    robot.gripper_open()
    robot.move_l(plan.retreat)
    return PickResult(None if width is None else True, width)

"""Pick and place with a UR5 and a parallel-jaw gripper: the grasp plan's waypoints executed through the
bridge, with the grasp checked on the jaws' opening where the gripper reports it."""

from __future__ import annotations

from dataclasses import dataclass

from robot_bridge.bridge import UR5
from robot_bridge.grasp import GraspPlan


@dataclass
class PickResult:
    """held: the jaws stopped on something (None when the gripper does not report its opening);
    width: their opening after closing (m) or None; reason: why the pick was abandoned, else ''."""

    held: bool | None
    width: float | None
    reason: str = ""


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

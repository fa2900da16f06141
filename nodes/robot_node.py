"""robot_node: picks up the object whose pose arrives on ``object_pose`` (camera frame) with a UR5 through
ur-rtde (a real robot or the simulated controller), one pick at a time.

States: idle -> planning -> moving -> idle (or failed); each change is published on ``robot_status``
(std_msgs/String, JSON: state, attempt, detail). Each attempt is ``robot_bridge.pick.attempt_pick``: while
planning, before any command is sent (the move home included), the estimate is checked
(``robot_bridge.plausibility``: the object resting on the table, in reach), the grasp is planned from the home
joints' TCP pose (forward kinematics; the arm is not moved to get it) and the plan is checked (no fingertip in
the table); a refusal sends nothing and ends the attempt as failed with the detail "implausible estimate: "
and the reason. Only then the arm moves home and on.
Parameters (``PARAMETERS``, each typed by its default): ``host``; ``hand_eye`` (T_base_cam, 16 floats
row-major); ``basket`` (floor centre x y z, base frame), ``table_z`` (the table top's height, m, base frame)
and ``home`` (joints, rad: each attempt starts there), by default the simulated cell's (``robot_bridge.cell``);
``bbox_min``/``bbox_size`` (the object's model box, m) and ``symmetry_axis`` (object frame; 0 0 0 for none);
``execute`` = pick (the whole pick-and-place) or pregrasp (stop above the object); ``speed``; ``dry_run``;
``wait_for_attempt`` (act only once per message on ``attempt``, as evaluator_node sends them; the status
carries that attempt's number). Poses arriving while it moves are ignored. ``results``: per attempt, picked,
missed, pregrasp, implausible or failed. Broadcasts the static transform base_link -> ``camera_frame`` (the
hand-eye). Parameters are checked where they enter (``check_parameters``): a NaN would switch a check off (e.g.
``table_z`` the envelope's table check).
"""

from __future__ import annotations

import dataclasses
import json
import threading

import numpy as np

from nodes.conversions import IDENTITY, matrix_to_transform, pose_msg_to_matrix
from nodes.ros import Node, StaticTransformBroadcaster, declare, latched, msgs, run_node
from pegasus_gen.errors import PegasusError
from robot_bridge.attempts import IMPLAUSIBLE_DETAIL
from robot_bridge.bridge import UR5, BridgeConfig
from robot_bridge.cell import SIM_CELL
from robot_bridge.kinematics import joints_problem
from robot_bridge.pick import PickTarget, attempt_pick
from robot_bridge.safety import SafetyEnvelope

PARAMETERS = (
    ("host", "127.0.0.1"), ("hand_eye", IDENTITY), ("basket", list(SIM_CELL.basket)),
    ("table_z", SIM_CELL.table_z),
    ("bbox_min", [-0.047, -0.047, -0.0525]), ("bbox_size", [0.094, 0.094, 0.105]),
    ("symmetry_axis", [0.0, 0.0, 1.0]), ("execute", "pick"), ("speed", 0.25), ("dry_run", False),
    ("wait_for_attempt", False), ("home", list(SIM_CELL.home)), ("camera_frame", "camera"))


def check_parameters(p: dict) -> None:
    """PegasusError naming the first of the parameters ``p`` that cannot be used: execute not pick/pregrasp, a list
    of the wrong length, a number that is not finite, a model box without size, home joints beyond the UR5's
    limits. (``table_z`` and ``speed`` are the safety envelope's to check.)"""
    if p["execute"] not in ("pick", "pregrasp"):
        raise PegasusError(f"robot_node: execute must be pick or pregrasp, got {p['execute']!r}")
    for name, n in (("hand_eye", 16), ("basket", 3), ("bbox_min", 3), ("bbox_size", 3), ("symmetry_axis", 3)):
        values = np.asarray(p[name], dtype=np.float64)
        if values.shape != (n,) or not np.isfinite(values).all():
            raise PegasusError(f"robot_node: {name} must be {n} finite numbers, got {p[name]}")
    if min(p["bbox_size"]) <= 0:
        raise PegasusError(f"robot_node: bbox_size must be positive (m), got {p['bbox_size']}")
    problem = joints_problem(p["home"])
    if problem is not None:
        raise PegasusError(f"robot_node: home: {problem}")


class RobotNode(Node):
    def __init__(self, **kwargs):
        super().__init__("robot_node", **kwargs)
        p = declare(self, PARAMETERS)
        check_parameters(p)
        self.T_base_cam = np.array(p["hand_eye"], dtype=np.float64).reshape(4, 4)
        p["table_z"] = float(p["table_z"])
        self.params = p
        self.cell = dataclasses.replace(SIM_CELL, basket=tuple(p["basket"]), table_z=p["table_z"],
                                        home=tuple(p["home"]))
        self.target = PickTarget(tuple(p["bbox_min"]), tuple(p["bbox_size"]),
                                 tuple(p["symmetry_axis"]) if any(p["symmetry_axis"]) else None)
        config = BridgeConfig(host=p["host"], speed=float(p["speed"]), dry_run=bool(p["dry_run"]),
                              envelope=SafetyEnvelope(table_z=p["table_z"]))
        config.envelope.check_motion(config.speed, config.acceleration)
        self.robot = UR5(config)
        self.status_pub = self.create_publisher(msgs.String, "robot_status", 10)
        self.tf_static = StaticTransformBroadcaster(self)  # where the camera is: base_link -> camera
        self.tf_static.sendTransform(matrix_to_transform(self.T_base_cam, "base_link", p["camera_frame"],
                                                         self.get_clock().now().to_msg()))
        self.create_subscription(msgs.PoseStamped, "object_pose", self.on_pose, 1)
        self.create_subscription(msgs.String, "attempt", self.on_attempt, latched())
        self.armed = None  # the attempt number a pose may start (with wait_for_attempt)
        self.busy = threading.Lock()
        self.attempts, self.results = 0, []

    def status(self, state: str, detail: str = "") -> None:
        self.status_pub.publish(msgs.String(data=json.dumps({"state": state, "attempt": self.attempts,
                                                             "detail": detail})))

    def on_attempt(self, msg) -> None:
        self.armed = json.loads(msg.data)["attempt"]

    def on_pose(self, msg) -> None:
        if self.params["wait_for_attempt"] and self.armed is None:
            return
        if not self.busy.acquire(blocking=False):
            return
        if self.params["wait_for_attempt"]:
            self.attempts, self.armed = self.armed, None
        else:
            self.attempts += 1
        threading.Thread(target=self._pick, args=(msg.pose,), daemon=True).start()

    def _connect(self) -> None:
        """Connect, or reconnect when the control program has ended (e.g. a protective stop was cleared)."""
        if self.robot.receive is None:
            self.robot.connect()
        elif not self.params["dry_run"] and not self.robot.control.isProgramRunning():
            self.robot.disconnect()
            self.robot.connect()

    def _refuse(self, reason: str) -> tuple[str, str]:
        self.results.append("implausible")
        self.get_logger().warning(f"robot_node: {IMPLAUSIBLE_DETAIL}{reason}; nothing was sent to the robot")
        return "failed", IMPLAUSIBLE_DETAIL + reason

    def _pick(self, pose) -> None:
        """One attempt for the estimate ``pose`` (a Pose message, camera frame), on its own thread; its final status
        published once the node takes poses again, so that a pose sent on that status is not dropped as busy."""
        try:
            state, detail = self._attempt(pose)
        finally:
            self.busy.release()
        self.status(state, detail)

    def _attempt(self, pose) -> tuple[str, str]:
        """The attempt's work: (its final state, "idle" or "failed", and the status detail)."""
        try:
            self.status("planning")
            try:
                T_cam_obj = pose_msg_to_matrix(pose)
            except ValueError:  # scipy: a zero-norm (or not finite) quaternion
                return self._refuse("the pose's quaternion is not a rotation")
            outcome = attempt_pick(self.robot, T_cam_obj, self.T_base_cam, self.target, self.cell,
                                   self.params["execute"], connect=self._connect, moving=lambda: self.status("moving"))
            if outcome.result == "implausible":
                return self._refuse(outcome.detail[len(IMPLAUSIBLE_DETAIL):])
            self.results.append(outcome.result)
            return "idle", outcome.detail
        except PegasusError as exc:
            self.results.append("failed")
            self.get_logger().error(f"robot_node: {exc}")
            return "failed", str(exc)

    def destroy_node(self) -> None:
        self.robot.disconnect()
        super().destroy_node()


NODE_CLASS = RobotNode


def main(args=None) -> None:
    """Console entry point (``ros2 run`` style)."""
    run_node(NODE_CLASS, args)

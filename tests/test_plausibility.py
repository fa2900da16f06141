"""Plausibility of pose estimates (robot_bridge.plausibility): a cup resting in the pick area passes; under
the table, floating, out of reach, outside the envelope, not finite, fingertips in the table are refused,
each for every random draw. robot_node refuses such an estimate before it sends the simulated controller
anything (its command log and the joints say so), and still moves for a plausible one; the evaluator counts
the refusal as an implausible estimate."""

import itertools
import json
import os
import re
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nodes import compat
from nodes.compat import Parameter
from nodes.conversions import matrix_to_pose_msg
from nodes.ros import REAL_ROS, msgs
from robot_bridge.attempts import FailureCause, failure_cause
from robot_bridge.cell import SIM_CELL
from robot_bridge.grasp import GraspParams, plan_grasp
from robot_bridge.kinematics import fk
from robot_bridge.plausibility import PlausibilityParams, plan_problem, pose_problem
from robot_bridge.safety import SafetyEnvelope
from robot_bridge.sim.world import HOME_Q

CUP_MIN, CUP_SIZE = np.array([-0.047, -0.047, -0.0525]), np.array([0.094, 0.094, 0.105])
BASKET = np.array([-0.15, -0.45, 0.0])
T_BASE_CAM = SIM_CELL.T_base_cam  # the sim cell's camera, base frame
DRAWS = 100


def pose(xyz, yaw=0.0, tilt_deg=0.0, tilt_axis=0.0) -> np.ndarray:
    """T_base_obj [4, 4]: turned by ``yaw`` about z, tilted ``tilt_deg`` about a horizontal axis at
    ``tilt_axis`` (rad), at ``xyz`` (m)."""
    T = np.eye(4)
    axis = np.array([np.cos(tilt_axis), np.sin(tilt_axis), 0.0])
    T[:3, :3] = (Rotation.from_rotvec(np.radians(tilt_deg) * axis) * Rotation.from_euler("z", yaw)).as_matrix()
    T[:3, 3] = xyz
    return T


def resting(rng: np.random.Generator) -> np.ndarray:
    """A cup in the evaluator's pick area (x -0.55..-0.38, y -0.12..0.12), any yaw, tilted up to 8 deg (an
    estimate's error), its lowest point within 1 cm of the table top."""
    T = pose([rng.uniform(-0.55, -0.38), rng.uniform(-0.12, 0.12), 0.0], rng.uniform(0, 2 * np.pi),
             rng.uniform(0, 8), rng.uniform(0, 2 * np.pi))
    corners = np.array(list(itertools.product(*zip(CUP_MIN, CUP_MIN + CUP_SIZE)))) @ T[:3, :3].T
    T[2, 3] = -corners[:, 2].min() + rng.uniform(-0.01, 0.01)
    return T


def plan_for(T_base_obj, table_z=0.0, params=None, bbox=(CUP_MIN, CUP_SIZE), axis=(0, 0, 1)):
    return plan_grasp(np.linalg.inv(T_BASE_CAM) @ T_base_obj, T_BASE_CAM, bbox[0], bbox[1], BASKET[:2], 0.006,
                      fk(HOME_Q), axis=axis, table_z=table_z, params=params, envelope=SafetyEnvelope())


# -- the checks ------------------------------------------------------------------------------------------------
def test_a_cup_resting_on_the_table_in_reach_is_plausible_and_so_is_its_grasp():
    T = pose([-0.45, 0.0, 0.0525])
    assert pose_problem(T, CUP_MIN, CUP_SIZE, 0.0) is None
    assert plan_problem(plan_for(T), 0.0) is None
    # on a table 10 cm higher, the same cup 10 cm higher (the basket on the floor below: not the table's business)
    T_high = pose([-0.45, 0.0, 0.1525])
    assert pose_problem(T_high, CUP_MIN, CUP_SIZE, 0.1) is None
    assert plan_problem(plan_for(T_high, table_z=0.1), 0.1) is None
    assert "floats 10.0 cm above" in pose_problem(T_high, CUP_MIN, CUP_SIZE, 0.0)  # the table at z = 0


@pytest.mark.parametrize("T, match", [
    (pose([-0.45, 0.0, 0.0525 - 0.05]), "5.0 cm below the table top"),
    (pose([-0.45, 0.0, 0.0525 + 0.06]), "floats 6.0 cm above the table top"),
    (pose([-0.9, 0.2, 0.0525]), "0.92 m from the base axis: out of reach"),
    (pose([-0.1, 0.05, 0.0525]), "0.11 m from the base axis: out of reach"),
    (pose([np.nan, 0.0, 0.0525]), "not a finite"),
    (np.diag([1.4, 1.4, 1.4, 1.0]) @ pose([-0.45, 0.0, 0.0525]), "not a rotation"),
])
def test_each_implausible_pose_is_refused_with_its_reason(T, match):
    reason = pose_problem(T, CUP_MIN, CUP_SIZE, 0.0)
    assert reason is not None and match in reason, reason
    assert "\n" not in reason


def test_a_centre_outside_the_safety_envelope_is_refused_and_the_tolerances_are_parameters():
    T = pose([-0.3, 0.5, 0.0525])  # 0.58 m from the base axis: in reach
    assert pose_problem(T, CUP_MIN, CUP_SIZE, 0.0) is None
    reason = pose_problem(T, CUP_MIN, CUP_SIZE, 0.0, envelope=SafetyEnvelope(y=(-0.4, 0.4)))
    assert "centre y = 0.500 m is outside the safety envelope" in reason
    sunk = pose([-0.45, 0.0, 0.0525 - 0.015])
    assert pose_problem(sunk, CUP_MIN, CUP_SIZE, 0.0) is None
    assert "below" in pose_problem(sunk, CUP_MIN, CUP_SIZE, 0.0, PlausibilityParams(below_table=0.01))


def test_a_grasp_whose_fingertips_would_enter_the_table_is_refused():
    flat = pose([-0.45, 0.0, 0.01])  # a box 2 cm high: the grasp would be 12 mm above the table
    bbox = (np.array([-0.04, -0.02, -0.01]), np.array([0.08, 0.04, 0.02]))
    assert pose_problem(flat, *bbox, 0.0) is None
    assert plan_problem(plan_for(flat, bbox=bbox, axis=None), 0.0) is None  # plan_grasp keeps the TCP 22 mm up
    too_low = plan_for(flat, bbox=bbox, axis=None, params=GraspParams(finger_clearance=0.005))
    assert too_low.grasp[2, 3] == pytest.approx(0.012)
    assert plan_problem(too_low, 0.0) == "the fingertips would reach 0.3 cm into the table at the grasp " \
                                         "(TCP z = 0.012 m)"
    # a plan made for another table (here 1 cm lower than the real one)
    assert "into the table at the grasp" in plan_problem(plan_for(flat, bbox=bbox, axis=None, table_z=-0.01), 0.01)


def test_random_resting_poses_pass_and_every_implausible_variant_of_each_is_refused(rng):
    for _ in range(DRAWS):
        T = resting(rng)
        assert pose_problem(T, CUP_MIN, CUP_SIZE, 0.0) is None, T
        assert plan_problem(plan_for(T), 0.0) is None
        checks = []
        down = T.copy()
        down[2, 3] -= rng.uniform(0.031, 0.3)  # the lowest point >= 2.1 cm below the table
        checks.append((down, "below the table top"))
        up = T.copy()
        up[2, 3] += rng.uniform(0.041, 0.5)
        checks.append((up, "above the table top"))
        far = T.copy()
        direction = rng.uniform(0, 2 * np.pi)
        far[:2, 3] = rng.uniform(0.81, 1.5) * np.array([np.cos(direction), np.sin(direction)])
        checks.append((far, "out of reach"))
        near = T.copy()
        near[:2, 3] = rng.uniform(0, 0.19) * np.array([np.cos(direction), np.sin(direction)])
        checks.append((near, "out of reach"))
        broken = T.copy()
        broken[rng.integers(3), rng.integers(4)] = rng.choice([np.nan, np.inf])
        checks.append((broken, "not a finite"))
        # the estimator's depth 1.4x too large, seen by the cell's oblique camera: farther down the ray
        T_cam_obj = np.linalg.inv(T_BASE_CAM) @ T
        T_cam_obj[:3, 3] *= 1.4
        checks.append((T_BASE_CAM @ T_cam_obj, "below the table top"))
        for bad, match in checks:
            reason = pose_problem(bad, CUP_MIN, CUP_SIZE, 0.0)
            assert reason is not None and match in reason, (match, reason, bad)
        low = plan_for(T)
        assert plan_problem(low, 0.0) is None
        assert "into the table" in plan_problem(low, rng.uniform(low.grasp[2, 3] - 0.015 + 1e-4, 0.3))


def test_the_evaluator_counts_a_refusal_as_an_implausible_estimate_and_other_failures_as_robot_errors():
    refused = {"state": "failed", "detail": "implausible estimate: the object's lowest point is 5.0 cm below"}
    assert failure_cause(False, refused, True, True) == FailureCause.IMPLAUSIBLE.value == "implausible estimate"
    other = {"state": "failed", "detail": "moveL failed: protective stop; the robot was stopped"}
    assert failure_cause(False, other, True, True) == "robot error: " + other["detail"]
    assert failure_cause(True, refused, True, True) == ""


# -- robot_node against the simulated controller ------------------------------------------------------------
def motion_lines(sim) -> list[str]:
    """The controller log's lines about arm motion (moveJ, moveL, stopJ, stopL)."""
    return [line for line in sim.log_lines() if re.search(r"\b(moveJ|moveL|stopJ|stopL)\b", line)]


def run_until_status(executor, statuses: list, count: int, timeout: float = 30.0) -> dict:
    """Spin until ``statuses`` holds ``count`` final (idle/failed) statuses; the last one."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        executor.spin_once(timeout_sec=0.05)
        final = [s for s in statuses if s["state"] in ("idle", "failed")]
        if len(final) >= count:
            return final[-1]
    raise AssertionError(f"robot_node did not finish within {timeout:.0f} s: {statuses}")


@pytest.mark.skipif(REAL_ROS, reason="runs the nodes on the stand-in layer")
def test_robot_node_sends_nothing_for_an_implausible_estimate_and_moves_for_a_plausible_one():
    import rtde_receive

    from nodes.robot_node import RobotNode
    from robot_bridge.sim.process import SimControllerProcess

    host = f"127.0.{os.getpid() % 200 + 20}.203"
    with SimControllerProcess(host, time_scale=3.0) as sim:
        receive = rtde_receive.RTDEReceiveInterface(host)
        compat.init()
        robot = probe = None
        try:
            robot = RobotNode(parameter_overrides=[Parameter("host", value=host),
                                                   Parameter("execute", value="pregrasp"),
                                                   Parameter("hand_eye", value=T_BASE_CAM.ravel().tolist())])
            probe = compat.Node("probe")
            statuses = []
            probe.create_subscription(msgs.String, "robot_status", lambda m: statuses.append(json.loads(m.data)), 10)
            pose_pub = probe.create_publisher(msgs.PoseStamped, "object_pose", 1)
            executor = compat.MultiThreadedExecutor()
            executor.add_node(robot)
            executor.add_node(probe)
            busy_at_final, publish = [], robot.status_pub.publish

            def recording(msg):  # a final status must mean the node takes the next pose (the loops send it then)
                if json.loads(msg.data)["state"] in ("idle", "failed"):
                    busy_at_final.append(robot.busy.locked())
                publish(msg)

            robot.status_pub.publish = recording

            def send(T_base_obj):
                pose_pub.publish(msgs.PoseStamped(header=msgs.Header(frame_id="camera"), pose=matrix_to_pose_msg(
                    np.linalg.inv(T_BASE_CAM) @ T_base_obj)))

            q0 = np.array(receive.getActualQ())
            np.testing.assert_allclose(q0, HOME_Q, atol=1e-9)
            for n, (T, words) in enumerate([(pose([-0.45, 0.0, 0.0525 - 0.08]), "below the table top"),
                                            (pose([-0.95, 0.1, 0.0525]), "out of reach")], start=1):
                send(T)
                status = run_until_status(executor, statuses, n)
                assert status["state"] == "failed" and status["detail"].startswith("implausible estimate: "), status
                assert words in status["detail"]
                assert failure_cause(False, status, True, True) == "implausible estimate"
                assert robot.results == ["implausible"] * n
            assert "moving" not in [s["state"] for s in statuses]
            time.sleep(0.1)
            np.testing.assert_allclose(receive.getActualQ(), q0, atol=1e-9)
            assert motion_lines(sim) == []
            assert not any("program" in line for line in sim.log_lines())  # not even the control script

            send(pose([-0.45, 0.05, 0.0525]))  # plausible: the robot goes to the pre-grasp
            status = run_until_status(executor, statuses, 3, timeout=40.0)
            assert status["state"] == "idle" and robot.results[-1] == "pregrasp", statuses
            assert any("moveL" in line for line in motion_lines(sim))
            assert np.abs(np.array(receive.getActualQ()) - q0).max() > 0.05
            assert busy_at_final == [False] * 3
            executor.shutdown()
        finally:
            for node in (robot, probe):
                if node is not None:
                    node.destroy_node()
            compat.shutdown()
            receive.disconnect()

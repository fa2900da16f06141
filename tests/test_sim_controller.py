"""The real ur-rtde 1.6.5 client and our bridge against the simulated UR controller (a child process on
its own loopback address): state, moveL/moveJ accuracy, asynchronous move then stop, the gripper on a
digital output, stopScript, reconnecting after a restart, refusals that send nothing, a killed
controller giving a clean error, a collision giving a protective stop."""

import itertools
import os
import time

import numpy as np
import pytest
import rtde_control
import rtde_io
import rtde_receive
from scipy.spatial.transform import Rotation

from robot_bridge.bridge import UR5, BridgeConfig, RobotConnectionError, RobotError
from robot_bridge.kinematics import fk, matrix_to_rtde_pose, rtde_pose_to_matrix
from robot_bridge.safety import SafetyEnvelope, UnsafeCommand
from robot_bridge.sim.process import SimControllerProcess
from robot_bridge.sim.world import HOME_Q
from robot_bridge.ur5_urdf import GRIPPER_STROKE, TCP_Z

_hosts = (f"127.0.{os.getpid() % 200 + 20}.{n}" for n in itertools.count(2))


@pytest.fixture
def controller():
    with SimControllerProcess(next(_hosts), time_scale=4.0) as sim:  # 4x real time, as the pick tests
        yield sim


def angle_deg(A, B):
    return np.degrees(Rotation.from_matrix(A[:3, :3].T @ B[:3, :3]).magnitude())


def test_ur_rtde_client_reads_state_moves_and_sets_io(controller):
    host = controller.host
    receive = rtde_receive.RTDEReceiveInterface(host)
    control = rtde_control.RTDEControlInterface(host)
    io = rtde_io.RTDEIOInterface(host)
    try:
        np.testing.assert_allclose(receive.getActualQ(), HOME_Q, atol=1e-9)
        tcp = np.eye(4)
        tcp[2, 3] = TCP_Z
        np.testing.assert_allclose(rtde_pose_to_matrix(receive.getActualTCPPose()), fk(HOME_Q, tcp), atol=1e-9)
        assert control.isProgramRunning() and receive.getRobotMode() == 7 and receive.getSafetyMode() == 1
        np.testing.assert_allclose(control.getTCPOffset(), [0, 0, TCP_Z, 0, 0, 0], atol=1e-12)

        target = rtde_pose_to_matrix(receive.getActualTCPPose())
        target[:3, 3] += [0.08, 0.05, -0.1]
        target[:3, :3] = Rotation.from_euler("z", 30, degrees=True).as_matrix() @ target[:3, :3]
        assert control.moveL(np.r_[target[:3, 3], Rotation.from_matrix(target[:3, :3]).as_rotvec()].tolist(), 0.3, 1.2)
        reached = rtde_pose_to_matrix(receive.getActualTCPPose())
        assert np.linalg.norm(reached[:3, 3] - target[:3, 3]) < 1e-3 and angle_deg(reached, target) < 0.5

        q = HOME_Q + [0.3, 0.1, -0.2, 0.2, 0.1, -0.4]
        assert control.moveJ(q.tolist(), 1.0, 2.0)
        np.testing.assert_allclose(receive.getActualQ(), q, atol=1e-4)

        start = np.array(receive.getActualTCPPose())
        far = start.copy()
        far[1] -= 0.3
        assert control.moveL(far.tolist(), 0.1, 0.5, True)  # asynchronous: returns at once
        deadline = time.monotonic() + 10.0  # the simulation may run slower than wall time under load
        while abs(receive.getActualTCPPose()[1] - start[1]) < 0.03 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert control.getAsyncOperationProgressEx().isAsyncOperationRunning()
        control.stopL(2.0)
        time.sleep(0.3)
        halted = np.array(receive.getActualTCPPose())
        assert 0.02 < abs(halted[1] - start[1]) < 0.25 and np.abs(receive.getActualQd()).max() < 1e-6

        assert receive.getStandardAnalogInput0() * 0.01 == pytest.approx(GRIPPER_STROKE, abs=1e-3)
        assert io.setStandardDigitalOut(0, True)
        time.sleep(1.0)
        assert receive.getDigitalOutState(0) and receive.getStandardAnalogInput0() * 0.01 < 0.005  # closed
        assert io.setStandardDigitalOut(0, False)
        time.sleep(1.0)
        assert receive.getStandardAnalogInput0() * 0.01 > GRIPPER_STROKE - 0.005

        control.stopScript()
        time.sleep(0.2)
        assert not control.isProgramRunning() and receive.getRuntimeState() == 1
    finally:
        for interface in (control, io, receive):
            interface.disconnect()
    log = "\n".join(controller.log_lines())
    assert "moveL" in log and "moveJ" in log and "stopL" in log and "stopScript" in log


def test_bridge_reconnects_after_the_controller_restarts():
    host = next(_hosts)
    robot = UR5(BridgeConfig(host=host, stale_after=0.5))
    with SimControllerProcess(host):
        robot.connect()
        robot.move_j(HOME_Q + [0.1, 0, 0, 0, 0, 0])
    with pytest.raises(RobotConnectionError):  # the controller is gone
        robot.move_j(HOME_Q)
    with SimControllerProcess(host):  # restarted: the same bridge connects again
        robot.disconnect()
        robot.connect()
        np.testing.assert_allclose(robot.joint_positions(), HOME_Q, atol=1e-9)
        robot.move_j(HOME_Q + [0.1, 0, 0, 0, 0, 0])
        np.testing.assert_allclose(robot.joint_positions(), HOME_Q + [0.1, 0, 0, 0, 0, 0], atol=1e-4)
        robot.disconnect()


def test_unsafe_commands_are_refused_and_nothing_is_sent(controller):
    envelope = SafetyEnvelope(z=(0.05, 0.9), min_height=0.05)
    with UR5(BridgeConfig(host=controller.host, envelope=envelope)) as robot:
        low = robot.tcp_pose()
        low[2, 3] = 0.02
        with pytest.raises(UnsafeCommand, match="above the table top"):
            robot.move_l(low)
        with pytest.raises(UnsafeCommand, match="speed"):
            robot.move_l(robot.tcp_pose(), speed=3.0)
        tilted = robot.tcp_pose()
        tilted[:3, :3] = Rotation.from_euler("x", 80, degrees=True).as_matrix() @ tilted[:3, :3]
        with pytest.raises(UnsafeCommand, match="tilted"):
            robot.move_l(tilted)
        scaled = robot.tcp_pose()  # a 70 degree tilt scaled to read as 50 degrees
        scaled[:3, :3] = Rotation.from_euler("x", 70, degrees=True).as_matrix() @ scaled[:3, :3]
        scaled[:3, :3] *= np.cos(np.radians(50)) / np.cos(np.radians(70))
        with pytest.raises(UnsafeCommand, match="not a rigid transform"):
            robot.move_l(scaled)
        with pytest.raises(UnsafeCommand, match="NaN"):
            robot.move_l([-0.4, -0.1, 0.4, np.nan, 0.0, 0.0])
        with pytest.raises(UnsafeCommand, match="speed 0"):
            robot.move_l(robot.tcp_pose(), speed=0.0)
        with pytest.raises(UnsafeCommand, match="joint limit"):
            robot.move_j(robot.joint_positions() + [20 * np.pi, 0, 0, 0, 0, 0])
    log = "\n".join(controller.log_lines())
    assert "moveL" not in log and "moveJ" not in log

    # two ends inside the 60 degree tilt cone (48.9 and 44.7 degrees), the SLERP between them outside it
    with UR5(BridgeConfig(host=controller.host)) as robot:
        ends = [robot.tcp_pose(), robot.tcp_pose()]
        for T, rotvec in zip(ends, ([1.0, -2.6, 1.26], [2.46, 1.48, 1.18])):
            T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
        robot.move_l(ends[0])
        with pytest.raises(UnsafeCommand, match="moveL refused at .* of the way: the tool is tilted"):
            robot.move_l(ends[1])
    assert sum("moveL" in line for line in controller.log_lines()) == 1  # the first end's only


def test_dry_run_sends_nothing(controller):
    with UR5(BridgeConfig(host=controller.host, dry_run=True)) as robot:
        target = robot.tcp_pose()
        target[0, 3] += 0.05
        robot.move_l(target)
        robot.gripper_close()
        np.testing.assert_allclose(robot.joint_positions(), HOME_Q, atol=1e-9)
    log = "\n".join(controller.log_lines())
    assert "moveL" not in log and "digital_output" not in log and "program" not in log


def test_killing_the_controller_mid_move_is_a_clean_error_not_a_hang(controller):
    with UR5(BridgeConfig(host=controller.host, stale_after=0.5)) as robot:
        target = robot.tcp_pose()
        target[1, 3] -= 0.3
        import threading

        threading.Timer(0.6, controller.kill).start()
        t0 = time.monotonic()
        with pytest.raises(RobotConnectionError, match="lost"):
            robot.move_l(target, speed=0.05)
        assert time.monotonic() - t0 < 5.0


def test_a_collision_is_a_protective_stop_and_the_bridge_reports_it(controller):
    envelope = SafetyEnvelope(z=(-0.5, 0.9), min_height=-0.5)  # the envelope lets it through; the table does not
    with UR5(BridgeConfig(host=controller.host, envelope=envelope)) as robot:
        down = robot.tcp_pose()
        down[2, 3] = -0.05  # the gripper body would go through the table top (z = 0)
        with pytest.raises(RobotError, match="protective stop"):
            robot.move_l(down, speed=0.2)
        assert robot.protective_stopped() and robot.tcp_pose()[2, 3] > 0.0


def test_sim_robot_command_refuses_an_address_in_use(controller):
    import subprocess
    import sys

    result = subprocess.run([sys.executable, "-m", "pegasus_gen.cli", "sim-robot", "--host", controller.host],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and "cannot listen on" in result.stderr and "Traceback" not in result.stderr


def test_the_controller_never_answers_done_to_what_it_did_not_do(controller):
    """Inverse kinematics answers from the UR5's kinematics (reproduced through FK); an unreachable pose, a
    NaN move and an unsupported mode (speedJ) end the program, so the client sees the failure; the cell
    survives and serves the next client; a second control client is refused, as a UR refuses registers in
    use, and the first keeps working."""
    host = controller.host
    receive = rtde_receive.RTDEReceiveInterface(host)
    control = rtde_control.RTDEControlInterface(host)
    try:
        pose = receive.getActualTCPPose()
        target = rtde_pose_to_matrix(pose)
        target[:3, 3] += [0.05, -0.03, 0.04]
        target[:3, :3] = Rotation.from_euler("y", 20, degrees=True).as_matrix() @ target[:3, :3]
        tcp = rtde_pose_to_matrix(control.getTCPOffset())
        for q in (control.getInverseKinematics(list(matrix_to_rtde_pose(target))),
                  control.getInverseKinematics(list(matrix_to_rtde_pose(target)), list(HOME_Q))):
            reached = fk(np.array(q), tcp)
            assert np.abs(reached[:3, 3] - target[:3, 3]).max() < 1e-6 and angle_deg(reached, target) < 1e-6
        with pytest.raises(RuntimeError, match="already in use"):
            rtde_control.RTDEControlInterface(host)
        assert control.moveL(list(matrix_to_rtde_pose(target)), 0.2, 1.0)  # the first client still drives the arm
        np.testing.assert_allclose(receive.getActualTCPPose()[:3], target[:3, 3], atol=1e-3)

        def speed_j(c):  # a realtime command: accepted at once, it fails when the program meets it
            c.speedJ([0.2, 0, 0, 0, 0, 0], 0.5, 0.1)
            time.sleep(0.3)
            return None

        bad = (lambda c: c.getInverseKinematics([3.0, 0.0, 0.3, 0.0, 3.14, 0.0]),  # out of reach: []
               lambda c: c.moveL([np.nan, *pose[1:]], 0.1, 0.5), speed_j)
        for call in bad:
            q_before = receive.getActualQ()
            assert not call(control) and not control.isProgramRunning()
            np.testing.assert_allclose(receive.getActualQ(), q_before, atol=1e-9)  # nothing moved
            control.disconnect()
            control = rtde_control.RTDEControlInterface(host)  # the cell serves the next client
            assert control.isProgramRunning() and not receive.isProtectiveStopped()
        assert control.moveL(pose, 0.2, 1.0)
        np.testing.assert_allclose(receive.getActualTCPPose()[:3], pose[:3], atol=1e-3)
    finally:
        control.disconnect()
        receive.disconnect()
    log = "\n".join(controller.log_lines())
    assert "refused: getInverseKinematics" in log and "refused: moveL [nan" in log
    assert "refused: speedJ is not supported" in log and "input_int_register_0 (IN_USE)" in log


def test_the_sim_cell_client_sets_up_queries_and_refuses_through_the_dashboard(controller, tmp_path):
    from pegasus_gen.errors import PegasusError
    from robot_bridge.sim.client import body_asset, body_name

    urdf = tmp_path / "box.urdf"
    urdf.write_text('<robot name="box"><link name="b"><inertial><mass value="0.1"/><inertia ixx="1e-4" iyy="1e-4" '
                    'izz="1e-4" ixy="0" ixz="0" iyz="0"/></inertial><collision><geometry><box size="0.04 0.04 0.04"/>'
                    '</geometry></collision></link></robot>')
    cell = controller.cell
    cell.set_basket((-0.25, -0.28, 0.0))
    name = body_name("box", 3)
    assert body_asset(name) == "box"
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", 0.4).as_matrix()
    T[:3, 3] = -0.45, 0.05, 0.0205
    cell.add(name, urdf, T)
    assert cell.names() == [name]
    np.testing.assert_allclose(cell.pose(name), T, atol=2e-3)  # at rest where it was put
    assert cell.in_basket(name) is False
    cell.remove(name)
    assert cell.names() == []
    with pytest.raises(LookupError):
        cell.pose(name)
    with pytest.raises(PegasusError, match="sim add"):
        cell.add("x", tmp_path / "missing.urdf", T)
    with pytest.raises(PegasusError, match="sim basket"):
        cell.set_basket((np.nan, 0, 0))

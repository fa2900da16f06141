"""Abuse of the robot side (issue 31, rows H4-H6 and the robot's medium and low rows): the simulated controller
refuses what a UR would refuse (joints beyond +-2 pi, absurd TCP offsets and rotation vectors) instead of
answering "done"; settings it cannot run with are one error line before any port opens, and a cell that dies
closes the ports; the dashboard answers bad ``sim`` commands with an error line and keeps the connection, and
bounds its lines; robot_node refuses parameters that would switch a check off."""

import itertools
import os
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
import rtde_control
import rtde_receive
from scipy.spatial.transform import Rotation

from nodes import compat
from nodes.compat import Parameter
from nodes.ros import REAL_ROS
from pegasus_gen.errors import PegasusError
from robot_bridge.kinematics import JOINT_LIMIT, fk, rtde_pose_to_matrix
from robot_bridge.sim.client import DASHBOARD_PORT, dashboard_command
from robot_bridge.sim.controller import SimController
from robot_bridge.sim.dashboard import MAX_LINE
from robot_bridge.sim.options import check_settings
from robot_bridge.sim.process import SimControllerProcess
from robot_bridge.sim.script import READY, Command, ScriptServer
from robot_bridge.sim.world import HOME_Q

BEYOND_LIMIT_Q = [7.0, -1.8, 1.8, -1.57, -1.57, 0.0]  # joint 0 past the UR5's +-2 pi
_hosts = (f"127.0.{os.getpid() % 200 + 20}.{n}" for n in itertools.count(120))


@pytest.fixture
def controller():
    with SimControllerProcess(next(_hosts), time_scale=4.0) as sim:
        yield sim


def dashboard(host: str, timeout: float = 5.0):
    """A dashboard connection (socket, line reader) past its welcome line."""
    conn = socket.create_connection((host, DASHBOARD_PORT), timeout=timeout)
    reader = conn.makefile("rb")
    assert reader.readline().startswith(b"Connected")
    return conn, reader


def ask(conn, reader, line: str) -> str:
    conn.sendall(line.encode() + b"\n")
    return reader.readline().decode().strip()


def wait_for(condition, timeout: float = 10.0) -> bool:
    """Whether ``condition()`` holds within ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.01)
    return bool(condition())


def test_the_simulator_refuses_what_a_ur_would_refuse_and_never_answers_done(controller):
    """H4 and the TCP row: joint targets beyond +-2 pi, a rotation vector of 1e300 rad, a NaN or 2 m TCP offset
    are refused (the client's call fails, nothing moves); inverse kinematics near joints beyond the limits
    answers joints within them; a moveL that would turn wrist 3 past +2 pi is a protective stop, not a spin."""
    host = controller.host
    receive = rtde_receive.RTDEReceiveInterface(host)
    control = rtde_control.RTDEControlInterface(host)
    try:
        tcp = control.getTCPOffset()
        pose = receive.getActualTCPPose()
        bad = (lambda c: c.moveJ(BEYOND_LIMIT_Q, 1.0, 2.0),
               lambda c: c.moveJ([100.0, -1.8, 1.8, -1.57, -1.57, 0.0], 1.0, 2.0),
               lambda c: c.moveL([*pose[:3], 1e300, 0.0, 0.0], 0.1, 0.5),
               lambda c: c.setTcp([np.nan, 0, 0, 0, 0, 0]), lambda c: c.setTcp([2.0, 0, 0, 0, 0, 0]))
        for call in bad:
            t0 = time.monotonic()
            assert not call(control) and time.monotonic() - t0 < 10.0  # refused, not hung (a hang ran for minutes)
            assert control.reuploadScript() and wait_for(control.isProgramRunning)  # the program ended: again
            np.testing.assert_allclose(receive.getActualQ(), HOME_Q, atol=1e-9)
            np.testing.assert_allclose(control.getTCPOffset(), tcp, atol=1e-12)

        q = control.getInverseKinematics(pose, [100.0, -1.8, 1.8, -1.57, -1.57, 0.0])
        assert np.abs(q).max() <= JOINT_LIMIT
        np.testing.assert_allclose(fk(q, rtde_pose_to_matrix(tcp)), rtde_pose_to_matrix(pose), atol=1e-9)

        near_limit = HOME_Q + [0, 0, 0, 0, 0, 6.0]
        assert control.moveJ(near_limit.tolist(), 1.0, 2.0)
        turned = rtde_pose_to_matrix(receive.getActualTCPPose())
        turned[:3, :3] = turned[:3, :3] @ Rotation.from_euler("z", 0.5).as_matrix()  # wrist 3 to 6.5 rad
        assert not control.moveL([*turned[:3, 3], *Rotation.from_matrix(turned[:3, :3]).as_rotvec()], 0.1, 0.5)
        assert wait_for(receive.isProtectiveStopped)  # the state stream arrives apart from the call's answer
        np.testing.assert_allclose(receive.getActualQ(), near_limit, atol=1e-4)
    finally:
        control.disconnect()
        receive.disconnect()
    log = "\n".join(controller.log_lines())
    assert "joint 0 = 7.000 rad beyond the joint limit" in log and "joint 0 = 100.000 rad" in log
    assert "rotation vector is 1e+300 rad long" in log and "refused: setTcp [nan" in log
    assert "the TCP would lie 2 m from the flange" in log and "would turn a joint past its limit" in log


def test_a_command_left_in_the_register_does_not_run_in_the_next_program():
    """After a refused command the client clears the register on its RTDE connection and uploads the script
    again on another; should the script arrive first, the new program must wait for the clear and not run the
    refused command again (it did, ended at once, and the client's reupload never saw a running program)."""
    controller = SimController(next(_hosts))  # not started: the cell is ticked by hand
    try:
        inputs = controller.state.inputs
        inputs.update({"input_int_register_0": int(Command.MOVEJ), "input_int_register_1": 0,
                       "input_double_register_6": 1.0, "input_double_register_7": 2.0})
        inputs.update({f"input_double_register_{i}": v for i, v in enumerate(BEYOND_LIMIT_Q)})
        ScriptServer(controller)._run_program("rtde_control", "reg_offset_int = 0\n")
        for _ in range(3):
            controller.program.tick()
        assert controller.state.program_running and not any("refused" in line for _, line in controller.log)
        inputs["input_int_register_0"] = int(Command.NO_CMD)  # the client's clear
        controller.program.tick()
        assert controller.state.outputs["output_int_register_0"] == READY
        inputs["input_int_register_0"] = int(Command.MOVEJ)  # the same command sent anew is refused
        controller.program.tick()
        assert not controller.state.program_running and any("joint 0 = 7.000 rad" in line for _, line in controller.log)
    finally:
        controller.stop()


@pytest.mark.parametrize("args, words", [(["--rate", "0"], "--rate must be a number within"),
                                         (["--time-scale", "nan"], "--time-scale must be a number within"),
                                         (["--host", "0.0.0.0"], "is not a loopback address")])
def test_sim_robot_refuses_settings_it_cannot_run_with_in_one_line(args, words):
    """H5 and the --host row: exit 2, one line, no traceback, and no port opened."""
    host = next(_hosts)
    result = subprocess.run([sys.executable, "-m", "pegasus_gen.cli", "sim-robot", "--host", host, *args],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and words in result.stderr and "Traceback" not in result.stderr


def test_the_controller_checks_its_settings_before_it_opens_a_port():
    host = next(_hosts)
    for kwargs in ({"rate": 0.0}, {"rate": np.inf}, {"time_scale": np.nan}, {"time_scale": -1.0}):
        with pytest.raises(PegasusError, match="must be a number within"):
            SimController(host, **kwargs)
        with pytest.raises(PegasusError, match="must be a number within"):
            SimControllerProcess(host, **kwargs)
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection((host, DASHBOARD_PORT), timeout=1.0)
    for remote in ("0.0.0.0", "10.1.2.3", "robot.example.com"):
        with pytest.raises(PegasusError, match="--allow-remote"):
            check_settings(remote, 125.0, 1.0)
        check_settings(remote, 125.0, 1.0, allow_remote=True)
    check_settings("localhost", 125.0, 1.0)


def test_a_cell_that_dies_closes_every_port_so_clients_fail_fast(monkeypatch):
    """H5: should the cell's thread die, the ports close: a connected client reads the end at once, a new one
    is refused."""
    controller = SimController(next(_hosts)).start()
    try:
        conn, reader = dashboard(controller.host)
        assert ask(conn, reader, "robotmode") == "Robotmode: RUNNING"

        def broken(why):
            raise RuntimeError("broken cell")

        monkeypatch.setattr(controller, "protective_stop", broken)
        controller.sim.collision = "a collision the cell cannot handle"
        t0 = time.monotonic()
        assert reader.readline() == b""  # the connection ends
        assert time.monotonic() - t0 < 10.0 and controller.fault == "RuntimeError: broken cell"
        with pytest.raises(ConnectionRefusedError):
            socket.create_connection((controller.host, DASHBOARD_PORT), timeout=1.0)
        conn.close()
    finally:
        controller.stop()


def test_bad_sim_commands_are_answered_and_the_connection_stays(controller, tmp_path):
    """Medium and low rows: a file that is not a URDF, a broken URDF, NaN numbers get an error line; the
    connection answers the next command; nothing was added."""
    broken = tmp_path / "broken.urdf"
    broken.write_text("<robot name='x'><link name='a'>")
    conn, reader = dashboard(controller.host)
    with conn, reader:
        for line in ("sim add x /etc/passwd 0 0 0 0 0 0 1", f"sim add x {tmp_path / 'missing.urdf'} 0 0 0 0 0 0 1",
                     f"sim add x {broken} -0.4 0 0.1 0 0 0 1", f"sim add x {broken} nan 0 0.1 0 0 0 1",
                     f"sim add x {broken} -0.4 0 0.1 0 0 0", "sim basket nan 0 0", "sim basket 0 0 inf"):
            assert ask(conn, reader, line).startswith("sim: error: "), line
            assert ask(conn, reader, "robotmode") == "Robotmode: RUNNING"
        assert ask(conn, reader, "sim list") == ""
    answer = dashboard_command(controller.host, "sim add x /etc/passwd 0 0 0 0 0 0 1")
    assert "/etc/passwd is not a .urdf file" in answer


def test_a_dashboard_line_is_bounded():
    """Low row: a line of MAX_LINE bytes is answered; a longer one (here 20 MB without a newline) is refused at
    once with an error line and the connection closed; the server answers the next client."""
    controller = SimController(next(_hosts)).start()
    try:
        conn, reader = dashboard(controller.host)
        assert ask(conn, reader, "x" * (MAX_LINE - 1)).startswith("could not understand")
        t0 = time.monotonic()
        try:
            conn.sendall(b"y" * 20_000_000)
        except ConnectionError:  # the server closed it part-way
            pass
        assert reader.readline().decode().startswith(f"error: command line longer than {MAX_LINE} bytes")
        assert time.monotonic() - t0 < 10.0  # linear: the quadratic buffer took 24 s
        conn.close()
        assert dashboard_command(controller.host, "robotmode") == "Robotmode: RUNNING"
    finally:
        controller.stop()


@pytest.mark.skipif(REAL_ROS, reason="runs the node on the stand-in layer")
@pytest.mark.parametrize("name, value, words", [("table_z", float("nan"), "table_z must be a finite number"),
                                                ("home", BEYOND_LIMIT_Q, "beyond the joint limit"),
                                                ("basket", [np.nan, 0.0, 0.0], "basket must be 3 finite numbers"),
                                                ("bbox_size", [0.1, 0.0, 0.1], "bbox_size must be positive"),
                                                ("speed", float("nan"), "speed nan m/s refused")])
def test_robot_node_refuses_parameters_that_would_switch_a_check_off(name, value, words):
    """H6: robot_node's parameters are checked where they enter (table_z went into the envelope as NaN, and the
    arm drove into the table)."""
    from nodes.robot_node import RobotNode

    compat.init()
    try:
        with pytest.raises(PegasusError, match=words):
            RobotNode(parameter_overrides=[Parameter(name, value=value)])
    finally:
        compat.shutdown()

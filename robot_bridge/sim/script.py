"""The simulated UR controller's script ports (30001-30003) and its control-script emulator.

Text sent to a script port is a program. ur-rtde's control script (``def rtde_control():``) is not interpreted
line by line: ``ControlProgram`` emulates what it does over the RTDE registers (signal ready / done in
output_int_register_0, async progress in output_int_register_2, commands in input_int_register_0 with arguments
in input_double_register_0.., register offset 0 or 24 as the script's injection says; async progress as ur-rtde
1.6 encodes it) for the commands of ``Command``. It never answers "done" to a command it did not carry out: a
command it does not simulate (speed, servo and force modes among them), a move with a non-finite or out-of-range
argument (a joint beyond the UR5's +-2 pi, a rotation vector longer than 2 pi), an absurd TCP offset and an
inverse kinematics without a solution end the program with a logged fault, as a runtime error ends a UR
program, so the client's call fails. A bare ``stopl``/``stopj``/``halt`` line stops the arm.
"""

from __future__ import annotations

import enum
import re
import socket

import numpy as np

from robot_bridge.kinematics import (
    fk,
    joints_problem,
    matrix_to_rtde_pose,
    nearest_ik,
    rtde_pose_problem,
    rtde_pose_to_matrix,
)
from robot_bridge.sim.world import MotionError

READY, DONE = 1, 2  # what the script signals in output_int_register_0
# ur-rtde 1.6.5's names of commands the emulator refuses (others are refused by number)
UNSUPPORTED = {2: "moveJ_IK", 4: "moveL_FK", 5: "moveC", 6: "forceMode", 7: "forceModeStop", 9: "speedJ",
               10: "speedL", 11: "servoJ", 12: "servoC", 18: "teachMode", 24: "servoL", 25: "toolContact",
               32: "moveP", 41: "jogStart", 45: "movePath"}
MAX_TCP_OFFSET = 1.0  # m from the flange: longer than any tool a UR5 carries


class Command(enum.IntEnum):
    """ur-rtde's control-script command numbers (input_int_register_0) that the emulator knows, as ur-rtde
    names them."""

    NO_CMD = 0
    MOVEJ = 1  # target q [0..5] (rad), speed [6], acceleration [7], async flag int 1
    MOVEL = 3  # target pose [0..5] (m, axis-angle rad), speed [6], acceleration [7], async flag int 1
    SET_TCP = 29  # TCP offset pose [0..5]
    GET_INVERSE_KINEMATICS_ARGS = 30  # pose [0..5], qnear [6..11] -> q in the output doubles
    PROTECTIVE_STOP = 31
    STOPL = 33  # deceleration [0], async flag int 1
    STOPJ = 34  # deceleration [0], async flag int 1
    GET_TCP_OFFSET = 40  # -> TCP offset pose in the output doubles
    SPEED_STOP = 15  # deceleration [0]: ends speed mode (none runs here) and brings the arm to rest
    SERVO_STOP = 16  # deceleration [0]: the same for servo mode
    GET_FORWARD_KINEMATICS_DEFAULT = 43  # -> TCP pose at the current joints in the output doubles
    GET_INVERSE_KINEMATICS_DEFAULT = 46  # pose [0..5] -> q nearest the current joints in the output doubles
    IS_STEADY = 47  # -> output int 1: 1 when the arm stands still
    STOP_SCRIPT = 255


class ScriptServer:
    """Script connections of ``controller`` (a ``controller.SimController``): ``serve(conn)`` reads programs
    from one connection and runs ur-rtde's control script as a ``ControlProgram``."""

    def __init__(self, controller):
        self.c = controller

    def serve(self, conn: socket.socket) -> None:
        c = self.c
        buffer = ""
        while not c.stopping.is_set():
            chunk = conn.recv(65536)
            if not chunk:
                return
            buffer += chunk.decode(errors="replace")
            match = re.search(r"^def (\w+)\(\):\n(.*?)^end\s*$", buffer, re.S | re.M)
            if match is None and buffer.lstrip().startswith(("stopl", "stopj", "halt")):
                c.record(f"script {buffer.strip()!r}")
                with c.lock:
                    c.sim.stop(1.5)
                buffer = ""
                continue
            if match is not None:
                self._run_program(match.group(1), match.group(2))
                buffer = buffer[match.end():]

    def _run_program(self, name: str, body: str) -> None:
        c = self.c
        c.record(f"program {name!r} received ({len(body)} characters)")
        if name != "rtde_control":
            c.record(f"program {name!r} is not the ur-rtde control script: not run")
            return
        offset = re.search(r"reg_offset_int\s*=\s*(\d+)", body)
        with c.lock:
            c.program = ControlProgram(c, int(offset.group(1)) if offset else 0)
            c.state.program_running = True


class ControlProgram:
    """What ur-rtde's control script does, over the RTDE registers (see the module docstring), for
    ``controller`` (a ``controller.SimController``) with register offset ``offset``; ``tick()`` runs once per
    cell step under the controller's lock."""

    def __init__(self, controller, offset: int):
        self.c, self.offset = controller, offset
        # A command already in the register was written for the program before this one: the client clears it
        # on its RTDE connection before it uploads the script, but that may reach us after the script did. The
        # program waits for the clear (as a UR, whose script compiles first, sees it), so nothing runs twice.
        self.executing = self._int(0) != Command.NO_CMD
        self.waiting_motion = False  # a synchronous move is running: 'done' when it ends
        self.async_motion = False  # an asynchronous one is: progress 'finished' when it ends
        self.async_writes, self.async_op_id = 0, 0
        self.end_reason = "stop script"  # why the program ends when a handler returns False
        self.handlers = {  # Command -> handler(cmd), True to go on, False to end the program
            Command.STOP_SCRIPT: self._stop_script, Command.MOVEJ: self._move, Command.MOVEL: self._move,
            Command.STOPL: self._stop_motion, Command.STOPJ: self._stop_motion, Command.SET_TCP: self._set_tcp,
            Command.GET_INVERSE_KINEMATICS_ARGS: self._inverse_kinematics,
            Command.GET_INVERSE_KINEMATICS_DEFAULT: self._inverse_kinematics, Command.GET_TCP_OFFSET: self._tcp_offset,
            Command.SPEED_STOP: self._stop_motion, Command.SERVO_STOP: self._stop_motion,
            Command.GET_FORWARD_KINEMATICS_DEFAULT: self._forward_kinematics, Command.IS_STEADY: self._is_steady,
            Command.PROTECTIVE_STOP: self._protective_stop}
        self._write_async_progress(-1)
        self._write_int(0, READY)

    def _int(self, i):
        return int(self.c.state.inputs.get(f"input_int_register_{i + self.offset}", 0))

    def _double(self, i):
        return float(self.c.state.inputs.get(f"input_double_register_{i + self.offset}", 0.0))

    def _doubles(self, start, n):
        return np.array([self._double(start + k) for k in range(n)])

    def _write_int(self, i, value):
        self.c.state.outputs[f"output_int_register_{i + self.offset}"] = int(value)

    def _write_double(self, i, value):
        self.c.state.outputs[f"output_double_register_{i + self.offset}"] = float(value)

    def _write_async_progress(self, value: int) -> None:
        """output_int_register_2 as ur-rtde 1.6's script writes it: bits 24-30 operation id (counted up when an
        operation starts, value 0), 16-22 write count, bit 15 running, 0-14 progress; value < 0: finished."""
        self.async_writes = (self.async_writes + 1) % 128
        if value == 0:
            self.async_op_id = (self.async_op_id + 1) % 128
        register = self.async_writes * 65536 + self.async_op_id * 16777216
        if value >= 0:
            register += (value & 0x7FFF) + 32768
        self._write_int(2, register)

    def tick(self) -> None:
        sim = self.c.sim
        if self.waiting_motion:
            if sim.moving:
                return
            self.waiting_motion = False
            self._write_int(0, DONE)
        if self.async_motion and not sim.moving:
            self.async_motion = False
            self._write_async_progress(-1)
        cmd = self._int(0)
        if cmd == Command.NO_CMD:
            self.executing = False
            self._write_int(0, READY)
        elif not self.executing:
            self.executing = True
            if not self._process(cmd):
                self.c.end_program(self.end_reason)
            elif not self.waiting_motion:
                self._write_int(0, DONE)

    def _process(self, cmd: int) -> bool:
        """Start command ``cmd``; False ends the program (stop script)."""
        handler = self.handlers.get(cmd)
        if handler is None:
            return self._fault(f"{UNSUPPORTED.get(cmd, f'command {cmd}')} is not supported by the simulated "
                               "controller")
        return handler(cmd)

    def _fault(self, why: str) -> bool:
        """Refuse the command: logged, and the program ends (the client's call fails); False."""
        self.c.record(f"refused: {why}")
        self.end_reason = "runtime exception"
        return False

    def _stop_script(self, cmd: int) -> bool:
        self.c.record("stopScript")
        return False

    def _move(self, cmd: int) -> bool:
        c, sim = self.c, self.c.sim
        target, speed, acc, asynchronous = self._doubles(0, 6), self._double(6), self._double(7), self._int(1) == 1
        name = "moveJ" if cmd == Command.MOVEJ else "moveL"
        problem = joints_problem(target) if cmd == Command.MOVEJ else rtde_pose_problem(target)
        if problem is None and not (np.isfinite([speed, acc]).all() and speed > 0 and acc > 0):
            problem = "speed and acceleration must be finite and positive"
        if problem is not None:
            return self._fault(f"{name} {target.tolist()} v={speed} a={acc}: {problem}")
        c.record(f"{name} {np.round(target, 5).tolist()} v={speed:g} a={acc:g}{' async' if asynchronous else ''}")
        sim.stop(4.0)
        try:
            if cmd == Command.MOVEJ:
                sim.move_joints(target, speed * c.state.speed_slider, acc)
            else:
                sim.move_linear(rtde_pose_to_matrix(target), speed * c.state.speed_slider, acc)
        except MotionError as exc:
            c.record(f"{name} failed: {exc}")
            c.protective_stop(str(exc))
            return False
        self._start_motion(asynchronous)
        return True

    def _stop_motion(self, cmd: int) -> bool:
        name = {Command.STOPL: "stopL", Command.STOPJ: "stopJ", Command.SPEED_STOP: "speedStop",
                Command.SERVO_STOP: "servoStop"}[cmd]
        deceleration = self._double(0)
        if not (np.isfinite(deceleration) and deceleration >= 0):
            return self._fault(f"{name} a={deceleration}: the deceleration must be finite and positive")
        self.c.record(f"{name} a={deceleration:g}")
        self.c.sim.stop(deceleration or 10.0)
        if cmd in (Command.STOPL, Command.STOPJ):
            self._start_motion(self._int(1) == 1)
        return True

    def _start_motion(self, asynchronous: bool) -> None:
        """A motion has started: report progress (asynchronous) or answer done when it ends (synchronous)."""
        if asynchronous:
            self.async_motion = True
            self._write_async_progress(0)
        else:
            self.waiting_motion = True

    def _set_tcp(self, cmd: int) -> bool:
        """The TCP offset T_flange_tcp from the pose given (at most ``MAX_TCP_OFFSET`` m from the flange)."""
        pose = self._doubles(0, 6)
        problem = rtde_pose_problem(pose)
        if problem is None and np.linalg.norm(pose[:3]) > MAX_TCP_OFFSET:
            problem = f"the TCP would lie {np.linalg.norm(pose[:3]):.3g} m from the flange (at most {MAX_TCP_OFFSET})"
        if problem is not None:
            return self._fault(f"setTcp {pose.tolist()}: {problem}")
        self.c.sim.tcp = rtde_pose_to_matrix(pose)
        self.c.record(f"setTcp {np.round(pose, 5).tolist()}")
        return True

    def _inverse_kinematics(self, cmd: int) -> bool:
        """q [6] whose TCP pose is the pose given, nearest qnear (given, or the current joints), each joint within the
        UR5's limits."""
        sim = self.c.sim
        pose = self._doubles(0, 6)
        qnear = self._doubles(6, 6) if cmd == Command.GET_INVERSE_KINEMATICS_ARGS else sim.q
        problem = rtde_pose_problem(pose) or (None if np.isfinite(qnear).all() else "qnear is not finite")
        if problem is not None:
            return self._fault(f"getInverseKinematics {pose.tolist()}: {problem}")
        q = nearest_ik(rtde_pose_to_matrix(pose) @ np.linalg.inv(sim.tcp), qnear)
        if q is None:
            return self._fault(f"getInverseKinematics {np.round(pose, 5).tolist()}: no solution (out of reach)")
        for k, v in enumerate(q):
            self._write_double(k, v)
        self.c.record(f"getInverseKinematics {np.round(pose, 5).tolist()} -> {np.round(q, 5).tolist()}")
        return True

    def _tcp_offset(self, cmd: int) -> bool:
        for k, v in enumerate(matrix_to_rtde_pose(self.c.sim.tcp)):
            self._write_double(k, v)
        return True

    def _forward_kinematics(self, cmd: int) -> bool:
        sim = self.c.sim
        for k, v in enumerate(matrix_to_rtde_pose(fk(sim.q, sim.tcp))):
            self._write_double(k, v)
        return True

    def _is_steady(self, cmd: int) -> bool:
        self._write_int(1, 0 if self.c.sim.moving else 1)
        return True

    def _protective_stop(self, cmd: int) -> bool:
        self.c.protective_stop("protective_stop command")
        return False

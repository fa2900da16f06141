"""A simulated UR controller on loopback that the unmodified ur-rtde client drives: dashboard server (29999),
RTDE (30004), script ports (30001-30003) in front of a PyBullet UR5 cell (``sim_world.RobotSim``).

What it serves:
- Dashboard: the welcome line, then one answer per command line (PolyscopeVersion, is in remote control,
  robotmode, safetystatus, programState, running, stop, play, power on/off, brake release,
  unlock protective stop, close safety popup, get serial number, get robot model, quit, ...).
- RTDE v2 (``rtde_protocol``): any output recipe of the variables the cell has (others as zeros of their
  type), streamed at the recipe's frequency (at most ``max_frequency``); input recipes of registers, digital
  outputs and the speed slider. Each connection has its own recipes; inputs go to one shared table.
- Script: text sent to 30001-30003 is a program. ur-rtde's control script (``def rtde_control():``) is not
  interpreted line by line: the controller emulates what it does over the RTDE registers (signal ready /
  done in output_int_register_0, async progress in output_int_register_2, commands in
  input_int_register_0 with arguments in input_double_register_0.., register offset 0 or 24 as the
  script's injection says; async progress as ur-rtde 1.6 encodes it): movej (1), movel (3), stopl (33), stopj (34), set_tcp (29), protective_stop
  (31), get_inverse_kin_args (30), is_steady (47), speed_stop (15), servo_stop (16), and stop script (255).
  Unknown commands are logged and answered done, so the client does not hang.
- Robot state: robot_mode 7 (RUNNING), safety_mode 1 (NORMAL) or 3 (PROTECTIVE_STOP), robot_status_bits
  (power on, program running), safety_status_bits (normal / protective stop), runtime_state 2 (PLAYING)
  while a program runs and 1 (STOPPED) otherwise, digital outputs; standard digital output
  ``gripper_output`` closes the gripper.

Every command that reaches the cell is appended to ``log`` (time, what), so tests can prove what was and
was not sent.
"""

from __future__ import annotations

import logging
import re
import socket
import struct
import threading
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from pegasus_gen.errors import PegasusError
from robot_bridge.kinematics import fk, matrix_to_pose, nearest_ik, pose_to_matrix
from robot_bridge.sim import rtde_protocol as rp
from robot_bridge.sim.client import DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORTS, dashboard_command
from robot_bridge.sim.world import HOME_Q, MotionError, RobotSim

log = logging.getLogger(__name__)

CONTROLLER_VERSION = (5, 11, 1, 108318)
POLYSCOPE_VERSION = "URSoftware 5.11.1.108318 (Mar 17 2021)"
ROBOT_MODE_RUNNING, SAFETY_NORMAL, SAFETY_PROTECTIVE_STOP = 7, 1, 3
RUNTIME_STOPPED, RUNTIME_PLAYING = 1, 2
READY, DONE = 1, 2
GRIPPER_METRES_PER_VOLT = 0.01  # the gripper reports its opening on standard analog input 0
REALTIME_COMMANDS = {24, 11, 9, 10, 6, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71}


@dataclass
class ControllerState:
    inputs: dict = field(default_factory=dict)  # name -> value, written by RTDE input packages
    outputs: dict = field(default_factory=dict)  # output registers written by the (emulated) program
    program_running: bool = False
    protective_stop: bool = False
    digital_out: int = 0  # standard digital outputs 0..7 as bits
    tool_digital_out: int = 0
    speed_slider: float = 1.0


class SimController:
    """The simulated controller. ``start()`` binds the ports on ``host`` (any 127.x.y.z keeps parallel runs
    apart) and runs the cell at ``rate`` Hz in a thread; ``stop()`` closes everything."""

    def __init__(self, host: str = "127.0.0.1", sim: RobotSim | None = None, rate: float = 125.0,
                 gripper_output: int = 0, max_frequency: float = 125.0, time_scale: float = 1.0):
        self.host, self.rate, self.gripper_output, self.max_frequency = host, rate, gripper_output, max_frequency
        self.time_scale = time_scale  # simulated seconds per wall-clock second (> 1: faster than real time)
        self.sim = sim if sim is not None else RobotSim()
        self.state = ControllerState()
        self.log: list[tuple[float, str]] = []
        self.lock = threading.RLock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._sockets: list[socket.socket] = []
        self._connections: set[socket.socket] = set()
        self._program: _ControlProgram | None = None
        self._t0 = time.monotonic()

    # -- lifecycle -----------------------------------------------------------------------------------
    def start(self) -> "SimController":
        for port, handler in [(DASHBOARD_PORT, self._serve_dashboard), (RTDE_PORT, self._serve_rtde)] + \
                [(p, self._serve_script) for p in SCRIPT_PORTS]:
            server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                server.bind((self.host, port))
            except OSError as exc:
                self.stop()
                raise PegasusError(f"simulated UR controller: cannot listen on {self.host}:{port} ({exc.strerror}; "
                                   f"another controller there? any other 127.x.y.z address will do)") from exc
            server.listen(8)
            self._sockets.append(server)
            self._spawn(self._accept_loop, server, handler)
        self._spawn(self._run_cell)
        return self

    def stop(self) -> None:
        self._stop.set()
        for s in self._sockets + list(self._connections):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2)
        self._sockets, self._threads = [], []
        self.sim.close()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    def _spawn(self, target, *args) -> None:
        t = threading.Thread(target=target, args=args, daemon=True)
        t.start()
        self._threads.append(t)

    def _accept_loop(self, server: socket.socket, handler) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.record(f"connection on port {server.getsockname()[1]}")
            self._connections.add(conn)
            self._spawn(self._handle, conn, handler)

    def _handle(self, conn: socket.socket, handler) -> None:
        try:
            handler(conn)
        except (ConnectionError, OSError, struct.error):
            pass
        finally:
            self._connections.discard(conn)
            conn.close()

    def record(self, what: str) -> None:
        self.log.append((time.monotonic() - self._t0, what))
        log.info("sim controller: %s", what)

    # -- robot state as RTDE variables ----------------------------------------------------------------
    def _values(self, names: list[str], kinds: list[str]) -> list:
        """The current values of the RTDE output variables ``names`` (of types ``kinds``); the state is
        read once per call (one forward kinematics), not once per variable."""
        s, sim = self.state, self.sim
        tcp_pose = tuple(matrix_to_pose(sim.tcp_pose()))
        state = {
            "timestamp": time.monotonic() - self._t0, "actual_q": tuple(sim.q), "target_q": tuple(sim.q),
            "actual_qd": tuple(sim.qd), "target_qd": tuple(sim.qd),
            "actual_TCP_pose": tcp_pose, "target_TCP_pose": tcp_pose,
            "tcp_offset": tuple(matrix_to_pose(sim.tcp)),
            "robot_mode": ROBOT_MODE_RUNNING, "joint_mode": (253,) * 6,
            "safety_mode": SAFETY_PROTECTIVE_STOP if s.protective_stop else SAFETY_NORMAL,
            "safety_status": SAFETY_PROTECTIVE_STOP if s.protective_stop else SAFETY_NORMAL,
            "safety_status_bits": (1 << 2) if s.protective_stop else 1,
            "robot_status_bits": 1 | (2 if s.program_running else 0),
            "runtime_state": RUNTIME_PLAYING if s.program_running else RUNTIME_STOPPED,
            "actual_digital_output_bits": s.digital_out | (s.tool_digital_out << 16),
            "speed_scaling": s.speed_slider, "target_speed_fraction": s.speed_slider,
            "standard_analog_input0": sim.gripper_width() / GRIPPER_METRES_PER_VOLT,
            "actual_main_voltage": 48.0, "actual_robot_voltage": 48.0, "joint_temperatures": (30.0,) * 6,
        }
        values = []
        for name, kind in zip(names, kinds):
            if name in s.outputs:
                values.append(s.outputs[name])
            elif name in s.inputs:
                values.append(s.inputs[name])
            elif name in state:
                values.append(state[name])
            else:  # a variable the simulation does not model reads as zero
                fmt = rp.FORMATS[kind]
                zero = False if kind == "BOOL" else 0
                values.append((zero,) * int(fmt[0]) if fmt[0].isdigit() else zero)
        return values

    def _apply_inputs(self, names: list[str], values: list) -> None:
        with self.lock:
            s = self.state
            new = dict(zip(names, values))
            s.inputs.update(new)
            for mask_name, value_name, attr in (("standard_digital_output_mask", "standard_digital_output",
                                                 "digital_out"),
                                                ("tool_digital_output_mask", "tool_digital_output",
                                                 "tool_digital_out")):
                if mask_name in new and value_name in new and new[mask_name]:
                    mask, value = new[mask_name], new[value_name]
                    before = getattr(s, attr)
                    after = (before & ~mask) | (value & mask)
                    setattr(s, attr, after)
                    self.record(f"{value_name} mask={mask:#04x} value={value:#04x}")
            if "speed_slider_mask" in new and new["speed_slider_mask"]:
                s.speed_slider = float(new.get("speed_slider_fraction", s.speed_slider))
            self.sim.set_gripper(bool(s.digital_out >> self.gripper_output & 1))

    # -- servers ---------------------------------------------------------------------------------------
    def _serve_dashboard(self, conn: socket.socket) -> None:
        conn.sendall(b"Connected: Universal Robots Dashboard Server\n")
        buffer = b""
        while not self._stop.is_set():
            chunk = conn.recv(4096)
            if not chunk:
                return
            buffer += chunk
            while b"\n" in buffer:
                line, buffer = buffer.split(b"\n", 1)
                command = line.decode(errors="replace").strip()
                answer = self._dashboard_answer(command)
                self.record(f"dashboard {command!r} -> {answer!r}")
                conn.sendall((answer + "\n").encode())
                if command == "quit":
                    return

    def _sim_answer(self, words: list[str]) -> str:
        """Simulation-only dashboard commands (no UR controller has them), for tests and the sim loop:
        ``sim add NAME URDF x y z qx qy qz qw``, ``sim pose NAME`` (-> x y z qx qy qz qw, base frame),
        ``sim remove NAME``, ``sim basket x y z`` (adds the basket), ``sim in_basket NAME`` (-> true/false),
        ``sim list`` (-> the object names), ``sim home`` (the arm back at its home joints, gripper open)."""
        from scipy.spatial.transform import Rotation

        sim = self.sim
        try:
            verb, args = words[0], words[1:]
            with self.lock:
                if verb == "add":
                    values = [float(v) for v in args[2:9]]
                    T = np.eye(4)
                    T[:3, :3] = Rotation.from_quat(values[3:]).as_matrix()
                    T[:3, 3] = values[:3]
                    sim.add_object(args[0], args[1], T)
                    return f"added {args[0]}"
                if verb == "pose":
                    T = sim.object_pose(args[0])
                    return " ".join(f"{v:.9f}" for v in [*T[:3, 3], *Rotation.from_matrix(T[:3, :3]).as_quat()])
                if verb == "remove":
                    sim.remove_object(args[0])
                    return f"removed {args[0]}"
                if verb == "basket":
                    sim.add_basket([float(v) for v in args[:3]])
                    return "basket added"
                if verb == "in_basket":
                    return str(sim.in_basket(args[0])).lower()
                if verb == "list":
                    return " ".join(sorted(sim.objects))
                if verb == "home":  # an operator moving the arm back by hand (teach mode) after a stop
                    sim.motion, sim.q, sim.qd = None, HOME_Q.copy(), np.zeros(6)
                    sim.set_gripper(False)
                    return "arm at home"
        except (IndexError, KeyError, ValueError) as exc:
            return f"sim: error: {exc!r}"
        return f"sim: unknown command {words}"

    def _dashboard_answer(self, command: str) -> str:
        s = self.state
        c = command.lower()
        if c.startswith("sim "):
            return self._sim_answer(command.split()[1:])
        state = "PROTECTIVE_STOP" if s.protective_stop else "NORMAL"
        answers = {
            "polyscopeversion": POLYSCOPE_VERSION, "version": ".".join(map(str, CONTROLLER_VERSION)),
            "is in remote control": "true", "robotmode": "Robotmode: RUNNING", "safetystatus": f"Safetystatus: {state}",
            "safetymode": f"Safetymode: {state}",
            "programstate": "PLAYING rtde_control" if s.program_running else "STOPPED <unnamed>",
            "running": f"Program running: {str(s.program_running).lower()}", "play": "Failed to execute: play",
            "pause": "Pausing program", "power on": "Powering on", "power off": "Powering off",
            "brake release": "Brake releasing", "close popup": "closing popup",
            "close safety popup": "closing safety popup", "get serial number": "20195300000",
            "get robot model": "UR5", "get loaded program": "No program loaded", "isprogramsaved": "true <unnamed>",
            "quit": "Disconnected"}
        if c == "stop":
            self._end_program("dashboard stop")
            return "Stopped"
        if c == "unlock protective stop":
            with self.lock:
                s.protective_stop = False
                self.sim.collision = None
            return "Protective stop releasing"
        if c in answers:
            return answers[c]
        return f"could not understand: '{command}'"

    def _serve_script(self, conn: socket.socket) -> None:
        buffer = ""
        while not self._stop.is_set():
            chunk = conn.recv(65536)
            if not chunk:
                return
            buffer += chunk.decode(errors="replace")
            match = re.search(r"^def (\w+)\(\):\n(.*?)^end\s*$", buffer, re.S | re.M)
            if match is None and buffer.lstrip().startswith(("stopl", "stopj", "halt")):
                self.record(f"script {buffer.strip()!r}")
                with self.lock:
                    self.sim.stop(1.5)
                buffer = ""
                continue
            if match is not None:
                self._run_program(match.group(1), match.group(2))
                buffer = buffer[match.end():]

    def _run_program(self, name: str, body: str) -> None:
        self.record(f"program {name!r} received ({len(body)} characters)")
        if name != "rtde_control":
            self.record(f"program {name!r} is not the ur-rtde control script: not run")
            return
        offset = re.search(r"reg_offset_int\s*=\s*(\d+)", body)
        with self.lock:
            self._program = _ControlProgram(self, int(offset.group(1)) if offset else 0)
            self.state.program_running = True

    def _end_program(self, why: str) -> None:
        with self.lock:
            if self._program is not None:
                self.record(f"program ended: {why}")
            self._program = None
            self.state.program_running = False
            self.sim.stop(4.0)

    def _serve_rtde(self, conn: socket.socket) -> None:
        outputs: dict[int, tuple[list[str], list[str], float]] = {}
        inputs: dict[int, tuple[list[str], list[str]]] = {}
        streaming = threading.Event()
        send_lock = threading.Lock()

        def send(kind, payload=b""):
            with send_lock:
                conn.sendall(rp.frame(kind, payload))

        def stream():
            try:
                stream_outputs()
            except OSError:  # the client went away
                streaming.clear()

        def stream_outputs():
            next_time = {rid: time.monotonic() for rid in outputs}
            while not self._stop.is_set() and streaming.is_set():
                now = time.monotonic()
                for rid, (names, types, freq) in list(outputs.items()):
                    if now >= next_time.get(rid, now):
                        with self.lock:
                            values = self._values(names, types)
                        send(rp.DATA_PACKAGE, bytes([rid]) + rp.pack_values(types, values))
                        next_time[rid] = max(next_time.get(rid, now) + 1 / freq, now)
                time.sleep(max(0.0, min(next_time.values(), default=now + 0.01) - time.monotonic()))

        try:
            while not self._stop.is_set():
                kind, payload = rp.read_frame(conn)
                if kind == rp.REQUEST_PROTOCOL_VERSION:
                    send(rp.REQUEST_PROTOCOL_VERSION, bytes([1 if struct.unpack(">H", payload)[0] == 2 else 0]))
                elif kind == rp.GET_URCONTROL_VERSION:
                    send(rp.GET_URCONTROL_VERSION, struct.pack(">IIII", *CONTROLLER_VERSION))
                elif kind == rp.SETUP_OUTPUTS:
                    frequency = struct.unpack(">d", payload[:8])[0]
                    names = [n for n in payload[8:].decode().split(",") if n]  # ur-rtde ends the list with a comma
                    types = [rp.output_type(n) or "NOT_FOUND" for n in names]
                    rid = len(outputs) + 1 if "NOT_FOUND" not in types else 0
                    if rid:
                        outputs[rid] = (names, types, min(max(frequency, 1.0), self.max_frequency))
                    else:
                        self.record(f"rtde output setup refused: unknown {[n for n, t in zip(names, types) if t == 'NOT_FOUND']}")
                    send(rp.SETUP_OUTPUTS, bytes([rid]) + ",".join(types).encode())
                elif kind == rp.SETUP_INPUTS:
                    names = [n for n in payload.decode().split(",") if n]
                    types = [rp.input_type(n) or "NOT_FOUND" for n in names]
                    rid = len(inputs) + 1 if "NOT_FOUND" not in types else 0
                    if rid:
                        inputs[rid] = (names, types)
                    else:
                        self.record(f"rtde input setup refused: unknown {[n for n, t in zip(names, types) if t == 'NOT_FOUND']}")
                    send(rp.SETUP_INPUTS, bytes([rid]) + ",".join(types).encode())
                elif kind == rp.START:
                    send(rp.START, b"\x01")
                    if outputs and not streaming.is_set():
                        streaming.set()
                        self._spawn(stream)
                elif kind == rp.PAUSE:
                    streaming.clear()
                    send(rp.PAUSE, b"\x01")
                elif kind == rp.DATA_PACKAGE:
                    rid = payload[0]
                    if rid in inputs:
                        names, types = inputs[rid]
                        self._apply_inputs(names, rp.unpack_values(types, payload[1:]))
                elif kind == rp.TEXT_MESSAGE:
                    pass
        finally:
            streaming.clear()

    # -- the cell --------------------------------------------------------------------------------------
    def _run_cell(self) -> None:
        dt = 1.0 / self.rate
        next_tick = time.monotonic()
        while not self._stop.is_set():
            with self.lock:
                if self._program is not None:
                    self._program.tick()
                if not self.state.protective_stop:
                    self.sim.advance(dt * self.time_scale)
                    if self.sim.collision:
                        self.protective_stop(self.sim.collision)
            next_tick += dt
            time.sleep(max(0.0, next_tick - time.monotonic()))

    def protective_stop(self, why: str = "external") -> None:
        """Enter a protective stop: the arm halts at once, the running program ends."""
        with self.lock:
            self.record(f"protective stop: {why}")
            self.state.protective_stop = True
            self.sim.motion = None
            self.sim.qd = np.zeros(6)
            self._end_program("protective stop")


class _ControlProgram:
    """What ur-rtde's control script does, over the RTDE registers (see the module docstring)."""

    def __init__(self, controller: SimController, offset: int):
        self.c, self.offset = controller, offset
        self.executing = False
        self.waiting_motion = False  # a synchronous move is running: 'done' when it ends
        self.async_motion = False  # an asynchronous one is: progress 'finished' when it ends
        self.async_writes, self.async_op_id = 0, 0
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
        if cmd in REALTIME_COMMANDS:
            self.c.record(f"realtime command {cmd} (not simulated)")
            self._write_int(0, READY)
        elif cmd == 0:
            self.executing = False
            self._write_int(0, READY)
        elif not self.executing:
            self.executing = True
            if not self._process(cmd):
                self.c._end_program("stop script")
            elif not self.waiting_motion:
                self._write_int(0, DONE)

    def _process(self, cmd: int) -> bool:
        """Start command ``cmd``; False ends the program (stop script)."""
        c, sim = self.c, self.c.sim
        if cmd == 255:
            c.record("stopScript")
            return False
        if cmd in (1, 3):  # movej, movel: target [0..5], speed [6], acceleration [7], async flag int 1
            target, speed, acc, asynchronous = self._doubles(0, 6), self._double(6), self._double(7), self._int(1) == 1
            name = "moveJ" if cmd == 1 else "moveL"
            c.record(f"{name} {np.round(target, 5).tolist()} v={speed:g} a={acc:g}{' async' if asynchronous else ''}")
            sim.stop(4.0)
            try:
                if cmd == 1:
                    sim.move_joints(target, speed * c.state.speed_slider, acc)
                else:
                    sim.move_linear(pose_to_matrix(target), speed * c.state.speed_slider, acc)
            except MotionError as exc:
                c.record(f"{name} failed: {exc}")
                c.protective_stop(str(exc))
                return False
            if asynchronous:
                self.async_motion = True
                self._write_async_progress(0)
            else:
                self.waiting_motion = True
            return True
        if cmd in (33, 34):  # stopl / stopj: deceleration [0], async flag int 1
            c.record(f"{'stopL' if cmd == 33 else 'stopJ'} a={self._double(0):g}")
            sim.stop(self._double(0) or 10.0)
            if self._int(1) == 1:
                self.async_motion = True
                self._write_async_progress(0)
            else:
                self.waiting_motion = True
            return True
        if cmd == 29:  # set_tcp
            sim.tcp = pose_to_matrix(self._doubles(0, 6))
            c.record(f"setTcp {np.round(self._doubles(0, 6), 5).tolist()}")
            return True
        if cmd == 30:  # get_inverse_kin_args: pose [0..5], qnear [6..11]
            T = pose_to_matrix(self._doubles(0, 6)) @ np.linalg.inv(sim.tcp)
            q = nearest_ik(T, self._doubles(6, 6))
            for k, v in enumerate(q if q is not None else sim.q):
                self._write_double(k, v)
            return True
        if cmd == 40:  # get_tcp_offset
            for k, v in enumerate(matrix_to_pose(sim.tcp)):
                self._write_double(k, v)
            return True
        if cmd == 43:  # get_forward_kinematics_default
            for k, v in enumerate(matrix_to_pose(fk(sim.q, sim.tcp))):
                self._write_double(k, v)
            return True
        if cmd == 47:  # is_steady
            self._write_int(1, 0 if sim.moving else 1)
            return True
        if cmd == 31:
            c.protective_stop("protective_stop command")
            return False
        c.record(f"command {cmd} not simulated: answered done")
        return True


class SimControllerProcess:
    """The simulated controller in a child process (ur-rtde's Python bindings hold the GIL while they wait
    on the controller, so client and controller cannot share a process): ``start()`` returns once the
    ports answer; ``log_lines()`` reads what reached the cell; ``kill()`` ends it abruptly."""

    def __init__(self, host: str = "127.0.0.1", log_path=None, rate: float = 125.0, time_scale: float = 1.0):
        import tempfile
        from pathlib import Path

        self.host, self.rate, self.time_scale = host, rate, time_scale
        self.log_path = Path(log_path) if log_path else Path(tempfile.mkstemp(prefix="sim_ur_", suffix=".log")[1])
        self.process = None

    def start(self, timeout: float = 20.0) -> "SimControllerProcess":
        import subprocess
        import sys

        self.process = subprocess.Popen([sys.executable, "-m", "pegasus_gen.cli", "sim-robot", "--host", self.host,
                                         "--log", str(self.log_path), "--rate", str(self.rate),
                                         "--time-scale", str(self.time_scale)],
                                        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if self.process.poll() is not None:
                raise RuntimeError(f"simulated UR controller exited: {self.process.stderr.read().decode()[-2000:]}")
            try:
                socket.create_connection((self.host, DASHBOARD_PORT), timeout=0.2).close()
                socket.create_connection((self.host, RTDE_PORT), timeout=0.2).close()
                return self
            except OSError:
                time.sleep(0.1)
        self.kill()
        raise RuntimeError(f"simulated UR controller did not come up on {self.host} within {timeout:.0f} s")

    def command(self, text: str, timeout: float = 5.0) -> str:
        """One dashboard command (e.g. the ``sim ...`` ones) and its answer line."""
        return dashboard_command(self.host, text, timeout)

    def log_lines(self) -> list[str]:
        return self.log_path.read_text().splitlines() if self.log_path.is_file() else []

    def stop(self) -> None:
        import subprocess

        if self.process is not None and self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.process = None

    def kill(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        self.process = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()



def serve(host: str = "127.0.0.1", log_path=None, rate: float = 125.0, time_scale: float = 1.0,
          basket=None) -> int:
    """Run a controller until SIGINT/SIGTERM (``pegasus sim-robot``)."""
    import signal

    logging.basicConfig(level=logging.INFO, format="%(message)s",
                        handlers=[logging.FileHandler(log_path)] if log_path else None, force=True)
    controller = SimController(host, rate=rate, time_scale=time_scale).start()
    if basket is not None:
        controller.sim.add_basket(basket)
    print(f"simulated UR controller on {host} (dashboard {DASHBOARD_PORT}, RTDE {RTDE_PORT}, "
          f"script {', '.join(map(str, SCRIPT_PORTS))}); Ctrl-C to stop", flush=True)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    stop.wait()
    controller.stop()
    return 0


"""The simulated UR controller on loopback that the unmodified ur-rtde client drives: ``SimController`` puts the
dashboard server (29999, ``dashboard``), the RTDE server (30004, ``rtde_server``) and the script ports
(30001-30003, ``script``) in front of a PyBullet UR5 cell (``world.RobotSim``) and runs the cell at a fixed rate;
``serve`` runs one until SIGINT/SIGTERM (``python -m robot_bridge.sim``, ``pegasus sim-robot``). Its settings are
checked before a port is opened (``options.check_settings``), and should the cell's thread ever die, every port
closes, so that clients fail at once instead of waiting on a cell that no longer runs.

Every command that reaches the cell is appended to ``SimController.log`` (time, what) and logged, so tests can
prove what was and was not sent.
"""

from __future__ import annotations

import logging
import signal
import socket
import struct
import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from pegasus_gen.errors import PegasusError
from robot_bridge.sim.client import DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORTS
from robot_bridge.sim.dashboard import DashboardServer
from robot_bridge.sim.options import check_settings
from robot_bridge.sim.rtde_server import RtdeServer
from robot_bridge.sim.script import ControlProgram, ScriptServer
from robot_bridge.sim.world import RobotSim

log = logging.getLogger(__name__)


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
    apart; another address only with ``allow_remote``) and runs the cell at ``rate`` Hz in a thread; ``stop()``
    closes everything. The servers share ``state``, ``sim`` and ``lock`` (held while either is read or changed).
    Settings out of range are a PegasusError here, before anything is opened."""

    def __init__(self, host: str = "127.0.0.1", sim: RobotSim | None = None, rate: float = 125.0,
                 gripper_output: int = 0, max_frequency: float = 125.0, time_scale: float = 1.0,
                 allow_remote: bool = False):
        check_settings(host, rate, time_scale, allow_remote)
        self.host, self.rate, self.gripper_output, self.max_frequency = host, rate, gripper_output, max_frequency
        self.time_scale = time_scale  # simulated seconds per wall-clock second (> 1: faster than real time)
        self.sim = sim if sim is not None else RobotSim()
        self.state = ControllerState()
        self.log: list[tuple[float, str]] = []
        self.lock = threading.RLock()
        self.stopping = threading.Event()  # set by stop() or a cell fault: every server loop ends
        self.fault: str | None = None  # why the cell's thread died, if it did (every port is then closed)
        self.program: ControlProgram | None = None  # the running control script, ticked with the cell
        self.input_owners: dict[str, object] = {}  # RTDE input field -> the connection that set it up
        self._threads: list[threading.Thread] = []
        self._sockets: list[socket.socket] = []
        self._connections: set[socket.socket] = set()
        self._t0 = time.monotonic()

    # -- lifecycle -----------------------------------------------------------------------------------
    def start(self) -> "SimController":
        script = ScriptServer(self)
        for port, handler in [(DASHBOARD_PORT, DashboardServer(self).serve), (RTDE_PORT, RtdeServer(self).serve)] + \
                [(p, script.serve) for p in SCRIPT_PORTS]:
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
            self.spawn(self._accept_loop, server, handler)
        self.spawn(self._run_cell)
        return self

    def stop(self) -> None:
        self._close_ports()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=2)
        self._sockets, self._threads = [], []
        self.sim.close()

    def _close_ports(self) -> None:
        """Set ``stopping`` and close the listening sockets and every connection: each server loop ends."""
        self.stopping.set()
        for s in self._sockets + list(self._connections):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    def spawn(self, target, *args) -> None:
        """Run ``target(*args)`` in a daemon thread that ``stop()`` joins."""
        t = threading.Thread(target=target, args=args, daemon=True)
        t.start()
        self._threads.append(t)

    def _accept_loop(self, server: socket.socket, handler) -> None:
        while not self.stopping.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.record(f"connection on port {server.getsockname()[1]}")
            self._connections.add(conn)
            self.spawn(self._handle, conn, handler)

    def _handle(self, conn: socket.socket, handler) -> None:
        try:
            handler(conn)
        except (ConnectionError, OSError, struct.error):
            pass
        finally:
            self._connections.discard(conn)
            conn.close()

    def elapsed(self) -> float:
        """Seconds since the controller was made (the log's and the RTDE timestamp's clock)."""
        return time.monotonic() - self._t0

    def record(self, what: str) -> None:
        self.log.append((self.elapsed(), what))
        log.info("sim controller: %s", what)

    # -- the cell --------------------------------------------------------------------------------------
    def _run_cell(self) -> None:
        """Run the cell until ``stop()``; should it fail, record why and close every port (``stop()`` still
        frees the rest)."""
        try:
            self._cell_loop()
        except Exception as exc:  # noqa: BLE001 - a bug of the simulation: no client may wait on a dead cell
            self.fault = f"{type(exc).__name__}: {exc}"
            self.record(f"cell fault: {self.fault}; every port closed")
            self._close_ports()

    def _cell_loop(self) -> None:
        dt = 1.0 / self.rate
        next_tick = time.monotonic()
        while not self.stopping.is_set():
            with self.lock:
                try:  # nothing a client sends may end the cell: a fault ends the program, as on a UR
                    if self.program is not None:
                        self.program.tick()
                except Exception as exc:  # noqa: BLE001 - any fault of the emulated script
                    self.record(f"program fault: {type(exc).__name__}: {exc}")
                    self.end_program("runtime exception")
                if not self.state.protective_stop:
                    try:
                        self.sim.advance(dt * self.time_scale)
                    except Exception as exc:  # noqa: BLE001 - the arm's state went bad: stop it
                        self.protective_stop(f"motion fault: {type(exc).__name__}: {exc}")
                    if self.sim.collision:
                        self.protective_stop(self.sim.collision)
            next_tick += dt
            time.sleep(max(0.0, next_tick - time.monotonic()))

    def end_program(self, why: str) -> None:
        """End the running control script (if any) and bring the arm to a stop."""
        with self.lock:
            if self.program is not None:
                self.record(f"program ended: {why}")
            self.program = None
            self.state.program_running = False
            self.sim.stop(4.0)

    def protective_stop(self, why: str = "external") -> None:
        """Enter a protective stop: the arm halts at once, the running program ends."""
        with self.lock:
            self.record(f"protective stop: {why}")
            self.state.protective_stop = True
            self.sim.motion = None
            self.sim.qd = np.zeros(6)
            self.end_program("protective stop")


def serve(host: str = "127.0.0.1", log_path=None, rate: float = 125.0, time_scale: float = 1.0,
          basket=None, allow_remote: bool = False) -> int:
    """Run a controller until SIGINT/SIGTERM (``python -m robot_bridge.sim``, ``pegasus sim-robot``); the flags
    are ``options.add_arguments``'s. 0 when stopped by a signal, 1 when the cell failed."""
    logging.basicConfig(level=logging.INFO, format="%(message)s",
                        handlers=[logging.FileHandler(log_path)] if log_path else None, force=True)
    if basket is not None and not np.isfinite(basket).all():
        raise PegasusError(f"simulated UR controller: --basket must be 3 finite numbers (m), got {basket}")
    controller = SimController(host, rate=rate, time_scale=time_scale, allow_remote=allow_remote)
    if basket is not None:
        controller.sim.add_basket(basket)
    controller.start()
    print(f"simulated UR controller on {host} (dashboard {DASHBOARD_PORT}, RTDE {RTDE_PORT}, "
          f"script {', '.join(map(str, SCRIPT_PORTS))}); Ctrl-C to stop", flush=True)
    signal.signal(signal.SIGTERM, lambda *_: controller.stopping.set())
    signal.signal(signal.SIGINT, lambda *_: controller.stopping.set())
    controller.stopping.wait()
    controller.stop()
    if controller.fault is not None:
        print(f"simulated UR controller stopped: the cell failed ({controller.fault})", file=sys.stderr)
        return 1
    return 0

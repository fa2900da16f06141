"""The simulated UR controller's dashboard server (port 29999) and its answer table: the welcome line, then one
answer per command line (PolyscopeVersion, is in remote control, robotmode, safetystatus, programState, running,
stop, play, power on/off, brake release, unlock protective stop, close safety popup, get serial number, get robot
model, quit, ...), plus the simulation-only ``sim ...`` commands that set up and query the cell. A command that
cannot be carried out is answered with an error line and the connection stays; a line longer than ``MAX_LINE``
bytes is answered with an error and the connection closed."""

from __future__ import annotations

import socket
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from robot_bridge.sim.world import HOME_Q, pb

CONTROLLER_VERSION = (5, 11, 1, 108318)
POLYSCOPE_VERSION = "URSoftware 5.11.1.108318 (Mar 17 2021)"
ANSWERS = {  # command (lower case) -> answer, where the answer does not depend on the controller's state
    "polyscopeversion": POLYSCOPE_VERSION, "version": ".".join(map(str, CONTROLLER_VERSION)),
    "is in remote control": "true", "robotmode": "Robotmode: RUNNING", "play": "Failed to execute: play",
    "pause": "Pausing program", "power on": "Powering on", "power off": "Powering off",
    "brake release": "Brake releasing", "close popup": "closing popup", "close safety popup": "closing safety popup",
    "get serial number": "20195300000", "get robot model": "UR5", "get loaded program": "No program loaded",
    "isprogramsaved": "true <unnamed>", "quit": "Disconnected"}
MAX_LINE = 16384  # bytes of one command line, its newline included


class DashboardServer:
    """Dashboard connections of ``controller`` (a ``controller.SimController``): ``serve(conn)`` answers one
    connection until it quits or closes."""

    def __init__(self, controller):
        self.c = controller

    def serve(self, conn: socket.socket) -> None:
        conn.sendall(b"Connected: Universal Robots Dashboard Server\n")
        with conn.makefile("rb") as reader:  # buffered: a line costs time linear in its length
            while not self.c.stopping.is_set():
                line = reader.readline(MAX_LINE)
                if not line.endswith(b"\n"):  # the connection closed, or the line is too long
                    if len(line) == MAX_LINE:
                        self.c.record(f"dashboard: a line longer than {MAX_LINE} bytes: connection closed")
                        conn.sendall(f"error: command line longer than {MAX_LINE} bytes\n".encode())
                    return
                command = line.decode(errors="replace").strip()
                answer = self.answer(command)
                self.c.record(f"dashboard {command!r} -> {answer!r}")
                conn.sendall((answer + "\n").encode())
                if command == "quit":
                    return

    def answer(self, command: str) -> str:
        """The answer line (without newline) to the dashboard command line ``command``."""
        c, s = self.c, self.c.state
        lower = command.lower()
        if lower.startswith("sim "):
            return self._sim_answer(command.split()[1:])
        state = "PROTECTIVE_STOP" if s.protective_stop else "NORMAL"
        answers = {**ANSWERS, "safetystatus": f"Safetystatus: {state}", "safetymode": f"Safetymode: {state}",
                   "programstate": "PLAYING rtde_control" if s.program_running else "STOPPED <unnamed>",
                   "running": f"Program running: {str(s.program_running).lower()}"}
        if lower == "stop":
            c.end_program("dashboard stop")
            return "Stopped"
        if lower == "unlock protective stop":
            with c.lock:
                s.protective_stop = False
                c.sim.collision = None
            return "Protective stop releasing"
        if lower in answers:
            return answers[lower]
        return f"could not understand: '{command}'"

    def _sim_answer(self, words: list[str]) -> str:
        """Simulation-only dashboard commands (no UR controller has them), for tests and the sim loop:
        ``sim add NAME URDF x y z qx qy qz qw``, ``sim pose NAME`` (-> x y z qx qy qz qw, base frame),
        ``sim remove NAME``, ``sim basket x y z`` (adds the basket), ``sim in_basket NAME`` (-> true/false),
        ``sim list`` (-> the object names), ``sim home`` (the arm back at its home joints, gripper open). URDF
        is the path of an existing ``.urdf`` file (an asset's ``model.urdf``); numbers are finite. A command that
        cannot be carried out is answered ``sim: error: ...``."""
        sim = self.c.sim
        try:
            verb, args = words[0], words[1:]
            with self.c.lock:
                if verb == "add":
                    values = _numbers(args[2:], 7)
                    urdf = Path(args[1])
                    if urdf.suffix != ".urdf" or not urdf.is_file():
                        raise ValueError(f"{args[1]} is not a .urdf file")
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
                    sim.add_basket(_numbers(args, 3))
                    return "basket added"
                if verb == "in_basket":
                    return str(sim.in_basket(args[0])).lower()
                if verb == "list":
                    return " ".join(sorted(sim.objects))
                if verb == "home":  # an operator moving the arm back by hand (teach mode) after a stop
                    sim.motion, sim.q, sim.qd = None, HOME_Q.copy(), np.zeros(6)
                    sim.set_gripper(False)
                    return "arm at home"
        except (IndexError, KeyError, ValueError, pb.error) as exc:
            return f"sim: error: {exc!r}"
        return f"sim: unknown command {words}"


def _numbers(words: list[str], n: int) -> list[float]:
    """``words``, exactly ``n`` of them, as finite numbers; ValueError otherwise."""
    values = [float(v) for v in words]
    if len(values) != n or not np.isfinite(values).all():
        raise ValueError(f"expected {n} finite numbers, got {' '.join(words)!r}")
    return values

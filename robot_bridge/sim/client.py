"""Talking to a (simulated) UR controller's dashboard server from outside: its ports, one command and its
answer, and ``SimCell``: every simulation-only ``sim ...`` command as a method, the one place that speaks them.

Objects in the cell are named ``ASSET#INDEX`` (``body_name``), so that whoever renders the cell finds each
body's asset (``body_asset``).
"""

from __future__ import annotations

import socket

import numpy as np
from scipy.spatial.transform import Rotation

from pegasus_gen.errors import PegasusError

DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORTS = 29999, 30004, (30001, 30002, 30003)
SIM_ERROR = "sim: "  # how the dashboard's answer to a sim command it could not carry out starts


def dashboard_command(host: str, text: str, timeout: float = 5.0) -> str:
    """Send one dashboard command to the controller at ``host`` and return its answer line."""
    with socket.create_connection((host, DASHBOARD_PORT), timeout=timeout) as conn:
        reader = conn.makefile("r")
        reader.readline()  # welcome
        conn.sendall((text + "\n").encode())
        return reader.readline().strip()


def body_name(asset: str, index: int) -> str:
    """The cell's name for the ``index``-th object made from ``asset``."""
    return f"{asset}#{index}"


def body_asset(name: str) -> str:
    """The asset a body of the cell was made from (its name up to '#')."""
    return name.split("#")[0]


class SimCell:
    """The simulated cell at ``host``, as its operator and the tests set it up and query it (poses: T_base_obj
    [4, 4], m, base frame). A command the cell cannot carry out raises PegasusError with its answer (``pose``
    of an unknown object: LookupError)."""

    def __init__(self, host: str, timeout: float = 5.0):
        self.host, self.timeout = host, timeout

    def command(self, text: str) -> str:
        """Any dashboard command (e.g. ``unlock protective stop``) and its answer line."""
        return dashboard_command(self.host, text, self.timeout)

    def _sim(self, text: str) -> str:
        answer = self.command(f"sim {text}")
        if answer.startswith(SIM_ERROR):
            raise PegasusError(f"simulated cell at {self.host}: sim {text.split()[0]}: {answer}")
        return answer

    def add(self, name: str, urdf, T_base_obj: np.ndarray) -> None:
        """Place a body ``name`` from ``urdf`` (a .urdf file) at T_base_obj [4, 4]; physics takes it from there."""
        x, y, z = T_base_obj[:3, 3]
        q = Rotation.from_matrix(T_base_obj[:3, :3]).as_quat()
        self._sim(f"add {name} {urdf} {x} {y} {z} {q[0]} {q[1]} {q[2]} {q[3]}")

    def pose(self, name: str) -> np.ndarray:
        """T_base_obj [4, 4] of body ``name``; LookupError when the cell has no such body (e.g. removed since
        it was listed)."""
        answer = self.command(f"sim pose {name}")
        if answer.startswith(SIM_ERROR):
            raise LookupError(f"simulated cell at {self.host}: no object {name!r} ({answer})")
        values = [float(v) for v in answer.split()]
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(values[3:]).as_matrix()
        T[:3, 3] = values[:3]
        return T

    def remove(self, name: str) -> None:
        self._sim(f"remove {name}")

    def names(self) -> list[str]:
        """The bodies in the cell."""
        return self._sim("list").split()

    def set_basket(self, centre) -> None:
        """Add the basket with its floor centre at ``centre`` [3] (m, base frame)."""
        x, y, z = (float(v) for v in centre)
        self._sim(f"basket {x} {y} {z}")

    def in_basket(self, name: str) -> bool:
        """Whether body ``name`` lies in the basket."""
        return self._sim(f"in_basket {name}") == "true"

    def home(self) -> None:
        """The arm back at its home joints and the gripper open, as an operator moves it after a stop."""
        self._sim("home")

"""Talking to a (simulated) UR controller's dashboard server from outside: its ports, one command and its
answer, and the simulation-only ``sim pose`` query."""

from __future__ import annotations

import socket

import numpy as np
from scipy.spatial.transform import Rotation

DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORTS = 29999, 30004, (30001, 30002, 30003)


def dashboard_command(host: str, text: str, timeout: float = 5.0) -> str:
    """Send one dashboard command to the controller at ``host`` and return its answer line."""
    with socket.create_connection((host, DASHBOARD_PORT), timeout=timeout) as conn:
        reader = conn.makefile("r")
        reader.readline()  # welcome
        conn.sendall((text + "\n").encode())
        return reader.readline().strip()


def sim_object_pose(host: str, name: str, timeout: float = 5.0) -> np.ndarray:
    """T_base_obj [4, 4] (m) of the simulated object ``name`` (the dashboard's ``sim pose NAME``); LookupError
    when the cell has no such object (e.g. removed since it was listed)."""
    answer = dashboard_command(host, f"sim pose {name}", timeout)
    if answer.startswith("sim: error"):
        raise LookupError(f"simulated cell at {host}: no object {name!r} ({answer})")
    values = [float(v) for v in answer.split()]
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(values[3:]).as_matrix()
    T[:3, 3] = values[:3]
    return T

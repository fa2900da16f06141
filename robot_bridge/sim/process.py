"""The simulated UR controller in a child process (``python -m robot_bridge.sim``), for tests, benchmarks and
the launch files: ur-rtde's Python bindings hold the GIL while they wait on the controller, so client and
controller cannot share a process."""

from __future__ import annotations

import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from robot_bridge.sim.client import DASHBOARD_PORT, RTDE_PORT, SimCell, dashboard_command
from robot_bridge.sim.options import check_settings


class SimControllerProcess:
    """The simulated controller in a child process: ``start()`` returns once the ports answer; ``log_lines()``
    reads what reached the cell; ``kill()`` ends it abruptly. A loopback ``host`` only; settings out of range are a
    PegasusError here (``options.check_settings``), before a process is started."""

    def __init__(self, host: str = "127.0.0.1", log_path=None, rate: float = 125.0, time_scale: float = 1.0):
        check_settings(host, rate, time_scale)
        self.host, self.rate, self.time_scale = host, rate, time_scale
        self.log_path = Path(log_path) if log_path else Path(tempfile.mkstemp(prefix="sim_ur_", suffix=".log")[1])
        self.process = None

    def start(self, timeout: float = 20.0) -> "SimControllerProcess":
        self.process = subprocess.Popen([sys.executable, "-m", "robot_bridge.sim", "--host", self.host,
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
        """One dashboard command and its answer line."""
        return dashboard_command(self.host, text, timeout)

    @property
    def cell(self) -> SimCell:
        """The simulated cell's ``sim ...`` commands."""
        return SimCell(self.host)

    def log_lines(self) -> list[str]:
        return self.log_path.read_text().splitlines() if self.log_path.is_file() else []

    def stop(self) -> None:
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

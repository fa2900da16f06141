"""The simulated controller's command-line flags (host, allow remote, log, rate, time scale, basket), defined once
for ``python -m robot_bridge.sim`` and ``pegasus sim-robot``, and the check of its settings (``check_settings``,
which the controller runs before it opens a port); this module imports nothing heavy, so a parser that carries
the flags builds fast (the controller itself loads PyBullet)."""

from __future__ import annotations

import argparse
import ipaddress
import math

from pegasus_gen.errors import PegasusError

RATE_HZ = (10.0, 1000.0)  # control rates taken (a UR runs at 125 or 500 Hz)
TIME_SCALE = (0.01, 20.0)  # simulated seconds per wall-clock second taken


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the flags ``controller.serve`` takes: ``host``, ``allow_remote``, ``log``, ``rate``, ``time_scale``,
    ``basket``."""
    parser.add_argument("--host", default="127.0.0.1", help="loopback address to listen on (any 127.x.y.z)")
    parser.add_argument("--allow-remote", action="store_true",
                        help="allow a --host that is not a loopback address (the robot controller is then open to "
                             "the network)")
    parser.add_argument("--log", help="write every command that reaches the cell to this file")
    parser.add_argument("--rate", type=float, default=125.0,
                        help=f"control rate, Hz ({RATE_HZ[0]:g} to {RATE_HZ[1]:g})")
    parser.add_argument("--time-scale", type=float, default=1.0,
                        help="simulated seconds per second (e.g. 4: motions take a quarter of their time; "
                             f"{TIME_SCALE[0]:g} to {TIME_SCALE[1]:g})")
    parser.add_argument("--basket", type=float, nargs=3, metavar=("X", "Y", "Z"),
                        help="put a basket with its floor centre here (base frame, m)")


def check_settings(host: str, rate: float, time_scale: float, allow_remote: bool = False) -> None:
    """PegasusError (one line naming the flag) unless ``rate`` (Hz) and ``time_scale`` are finite numbers within
    ``RATE_HZ`` and ``TIME_SCALE`` and ``host`` is a loopback address ("localhost" or 127.x.y.z), or
    ``allow_remote`` is given."""
    for flag, value, (lo, hi) in (("--rate", rate, RATE_HZ), ("--time-scale", time_scale, TIME_SCALE)):
        if not (math.isfinite(value) and lo <= value <= hi):
            raise PegasusError(f"simulated UR controller: {flag} must be a number within [{lo:g}, {hi:g}], got {value}")
    if allow_remote or host == "localhost":
        return
    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False
    if not loopback:
        raise PegasusError(f"simulated UR controller: --host {host} is not a loopback address; a robot controller "
                           "listening there is open to the network (add --allow-remote if that is meant)")

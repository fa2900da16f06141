"""The simulated controller's command-line flags (host, log, rate, time scale, basket), defined once for
``python -m robot_bridge.sim`` and ``pegasus sim-robot``; this module imports nothing heavy, so a parser that
carries the flags builds fast (the controller itself loads PyBullet)."""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the flags ``controller.serve`` takes: ``host``, ``log``, ``rate``, ``time_scale``, ``basket``."""
    parser.add_argument("--host", default="127.0.0.1", help="loopback address to listen on (any 127.x.y.z)")
    parser.add_argument("--log", help="write every command that reaches the cell to this file")
    parser.add_argument("--rate", type=float, default=125.0, help="control rate, Hz")
    parser.add_argument("--time-scale", type=float, default=1.0,
                        help="simulated seconds per second (e.g. 4: motions take a quarter of their time)")
    parser.add_argument("--basket", type=float, nargs=3, metavar=("X", "Y", "Z"),
                        help="put a basket with its floor centre here (base frame, m)")

"""``python -m robot_bridge.sim [--host H [--allow-remote]] [--log FILE] [--rate HZ] [--time-scale S]
[--basket X Y Z]``: run the simulated UR controller until Ctrl-C / SIGTERM; a bad flag value or a busy address is
one error line, exit 2."""

from __future__ import annotations

import argparse
import sys

from pegasus_gen.errors import PegasusError
from robot_bridge.sim.controller import serve
from robot_bridge.sim.options import add_arguments


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m robot_bridge.sim",
                                     description="the simulated UR5 controller that ur-rtde clients drive")
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return serve(args.host, args.log, args.rate, args.time_scale, args.basket, args.allow_remote)
    except PegasusError as exc:
        print(f"robot_bridge.sim: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

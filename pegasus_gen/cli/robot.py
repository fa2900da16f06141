"""`pegasus sim-robot`: the simulated UR5 controller that ur-rtde clients drive."""

from __future__ import annotations

from robot_bridge.sim.options import add_arguments


def cmd_sim_robot(args) -> int:
    from robot_bridge.sim.controller import serve

    return serve(args.host, args.log, args.rate, args.time_scale, args.basket, args.allow_remote)


def add_commands(sub) -> None:
    p = sub.add_parser("sim-robot", help="run the simulated UR5 controller that ur-rtde clients drive (Ctrl-C stops)")
    add_arguments(p)
    p.set_defaults(func=cmd_sim_robot)

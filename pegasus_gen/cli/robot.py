"""`pegasus sim-robot`: the simulated UR5 controller that ur-rtde clients drive."""

from __future__ import annotations


def cmd_sim_robot(args) -> int:
    from robot_bridge.sim_controller import serve

    return serve(args.host, args.log, args.rate, args.time_scale, args.basket)


def add_commands(sub) -> None:
    p = sub.add_parser("sim-robot", help="run the simulated UR5 controller that ur-rtde clients drive (Ctrl-C stops)")
    p.add_argument("--host", default="127.0.0.1", help="loopback address to listen on (any 127.x.y.z)")
    p.add_argument("--log", help="write every command that reaches the cell to this file")
    p.add_argument("--rate", type=float, default=125.0, help="control rate, Hz")
    p.add_argument("--time-scale", type=float, default=1.0,
                   help="simulated seconds per second (e.g. 4: motions take a quarter of their time)")
    p.add_argument("--basket", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="put a basket with its floor centre here (base frame, m)")
    p.set_defaults(func=cmd_sim_robot)

"""`pegasus launch` and `pegasus sim-grasp`: launch files run without ROS, and the closed-loop grasp evaluation."""

from __future__ import annotations

from pathlib import Path

from pegasus_gen.cli import options
from pegasus_gen.errors import PegasusError


def cmd_launch(args) -> int:
    import importlib.util

    from nodes.launch import run, run_processes

    if not args.processes:
        nodes = run(args.file, args.arguments)
        print(f"launch: {len(nodes)} node(s) ran: {', '.join(n.get_name() for n in nodes)}")
        return 0
    if importlib.util.find_spec("rclpy") is None:
        raise PegasusError("launch --processes runs each node on the real rclpy: install the ros extra "
                           "(pip install '.[ros]') or ROS 2")
    if args.log_dir:
        Path(args.log_dir).mkdir(parents=True, exist_ok=True)
    codes = run_processes(args.file, args.arguments, log_dir=args.log_dir)
    print(f"launch: {len(codes)} process(es) on the real rclpy: "
          f"{', '.join(f'{name} exited {code}' for name, code in codes.items())}")
    return 0 if not any(codes.values()) else 1


def cmd_sim_grasp(args) -> int:
    import json

    from nodes.launch import run

    overrides = [f"pose_source:={'ground_truth' if args.ground_truth else 'dope'}", f"attempts:={args.attempts}",
                 f"objects:={args.objects}", f"host:={args.host}", f"time_scale:={args.time_scale}",
                 f"report:={args.out}", f"seed:={args.seed}", f"device:={args.device}", f"use_pose:={args.use_pose}"]
    if args.model:
        overrides.append(f"model:={args.model}")
    elif not args.ground_truth:
        raise PegasusError("sim-grasp: give --model MODEL.onnx (or --ground-truth to measure grasping alone)")
    if args.library:
        overrides.append(f"library:={args.library}")
    bag = None
    if args.record:
        from nodes.bag import bag_directory

        bag = bag_directory(args.record)  # refused here, before anything runs, when it exists
        overrides.append(f"record:={bag}")
    run("sim_pick_place.launch.py", overrides)
    report = json.loads((Path(args.out) / "report.json").read_text())
    print(f"sim-grasp ({report['pose_source']} poses): {report['successes']} of {report['attempts']} in the basket; "
          f"failures: {report['failure_causes'] or 'none'}")
    print(f"report: {Path(args.out) / 'report.json'}    strip: {Path(args.out) / 'strip.png'}")
    if bag is not None:
        print(f"bag: {bag} (ros2 bag info/play it; Foxglove opens the .mcap inside)")
    return 0


def add_commands(sub) -> None:
    from nodes.launch import installed_launch_files

    p = sub.add_parser("launch", help="run a ROS 2-style launch file without ROS: pegasus launch FILE [name:=value]",
                       epilog=f"installed launch files: {', '.join(installed_launch_files())}")
    p.add_argument("file", help="a *.launch.py file, or the name of an installed one")
    p.add_argument("arguments", nargs="*", metavar="name:=value")
    p.add_argument("--processes", action="store_true",
                   help="each node a process of its own on the real rclpy (the ros extra), talking DDS, as ros2 launch "
                        "runs them; ROS_DOMAIN_ID from the environment (default: one process on the stand-in)")
    p.add_argument("--log-dir", help="with --processes: each node's output in DIR/<executable>.log")
    p.set_defaults(func=cmd_launch)

    p = sub.add_parser("sim-grasp",
                       help="closed-loop grasp evaluation in the simulated cell (sim_pick_place.launch.py)")
    p.add_argument("--model", help="DOPE ONNX export")
    p.add_argument("--ground-truth", action="store_true", help="drive the robot with the true poses (grasping alone)")
    p.add_argument("--use-pose", choices=("refined", "raw"), default="refined",
                   help="the robot acts on DOPE's pose refined with the camera's depth, or on DOPE's pose as it is")
    p.add_argument("--attempts", type=int, default=20)
    p.add_argument("--objects", default="noodle_cup_red,noodle_cup_curry", help="asset names, comma-separated")
    p.add_argument("--out", default="out/sim_grasp", help="report folder")
    p.add_argument("--record", metavar="BAG",
                   help="record every topic into this new rosbag2 bag (MCAP; NAME.mcap makes NAME/NAME.mcap)")
    options.add_host(p)
    p.add_argument("--time-scale", type=float, default=2.0, help="simulated seconds per second")
    options.add_library(p)
    options.add_seed(p)
    options.add_device(p, what="splat renderer")
    p.set_defaults(func=cmd_sim_grasp)

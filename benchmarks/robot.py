"""Pick-and-place cycle time in the simulated UR5 cell, through the real ur-rtde client, at real time.

Usage: python benchmarks/robot.py [--picks 5] [--time-scale 1.0]

Prints the wall time of the whole cycle (open, approach, grasp, lift, carry to the basket, release,
retreat): mean, min, max over the picks, and how many cups landed in the basket.
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np
from scipy.spatial.transform import Rotation

from pegasus_gen.assets.demo import build_demo_library
from pegasus_gen.assets.library import AssetLibrary
from robot_bridge.bridge import UR5, BridgeConfig, GripperConfig
from robot_bridge.grasp import plan_grasp
from robot_bridge.pick import pick_and_place
from robot_bridge.sim.client import sim_object_pose
from robot_bridge.sim.process import SimControllerProcess

HOST = "127.0.0.211"
BASKET = np.array([-0.15, -0.45, 0.0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--picks", type=int, default=5)
    parser.add_argument("--time-scale", type=float, default=1.0)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp, SimControllerProcess(HOST, time_scale=args.time_scale) as sim:
        lib = AssetLibrary(tmp)
        build_demo_library(lib)
        asset = lib.get("noodle_cup_red")
        cup = asset.urdf_path
        box_min, box_size = asset.mesh.bounds[0], np.ptp(asset.mesh.bounds, axis=0)  # model frame, m
        sim.command(f"sim basket {BASKET[0]} {BASKET[1]} {BASKET[2]}")
        config = BridgeConfig(host=HOST, speed=0.4, acceleration=1.5, gripper=GripperConfig(settle_s=0.6))
        cycles, landed = [], 0
        with UR5(config) as robot:
            for _ in range(args.picks):
                x, y, yaw = rng.uniform(-0.55, -0.35), rng.uniform(-0.15, 0.15), rng.uniform(0, 2 * np.pi)
                q = Rotation.from_euler("z", yaw).as_quat()
                sim.command(f"sim add cup {cup} {x} {y} {-box_min[2] + 0.002} {q[0]} {q[1]} {q[2]} {q[3]}")
                time.sleep(0.5 / args.time_scale)  # settles
                plan = plan_grasp(sim_object_pose(HOST, "cup"), np.eye(4), box_min, box_size, BASKET[:2], 0.006,
                                  robot.tcp_pose(), axis=[0, 0, 1], envelope=config.envelope)
                t = time.perf_counter()
                result = pick_and_place(robot, plan)
                cycles.append(time.perf_counter() - t)
                time.sleep(0.1)
                landed += sim.command("sim in_basket cup") == "true" and bool(result.held)
                sim.command("sim remove cup")
    cycles = np.array(cycles)
    print(f"pick-and-place cycle at time scale {args.time_scale:g} (0.4 m/s, 1.5 m/s^2, 0.6 s gripper settle): "
          f"mean {cycles.mean():.2f} s, min {cycles.min():.2f} s, max {cycles.max():.2f} s; "
          f"{landed} of {args.picks} in the basket")


if __name__ == "__main__":
    main()

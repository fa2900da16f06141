"""Pick-and-place cycle time in the simulated UR5 cell, through the real ur-rtde client, at real time.

Usage: python benchmarks/robot.py [--picks 5] [--time-scale 1.0]

Each pick is the checked attempt robot_node makes (``robot_bridge.pick.attempt_pick``) on the cup's true pose
(the camera at the base): the gates, then home, open, approach, grasp, lift, carry to the cell's basket,
release, retreat. Prints the wall time of the motion (from the move home to the retreat): mean, min, max over
the picks, and how many cups landed in the basket.
"""

from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np
from scipy.spatial.transform import Rotation

from pegasus_gen.assets.demo_library import build_demo_library
from pegasus_gen.assets.library import AssetLibrary
from robot_bridge.bridge import UR5, BridgeConfig, GripperConfig
from robot_bridge.cell import SIM_CELL
from robot_bridge.pick import PickTarget, attempt_pick
from robot_bridge.sim.process import SimControllerProcess

HOST = "127.0.0.211"


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
        box_min, box_size = asset.mesh.bounds[0], np.ptp(asset.mesh.bounds, axis=0)  # model frame, m
        target = PickTarget(tuple(box_min), tuple(box_size), (0.0, 0.0, 1.0))
        sim_cell = sim.cell
        sim_cell.set_basket(SIM_CELL.basket)
        config = BridgeConfig(host=HOST, speed=0.4, acceleration=1.5, gripper=GripperConfig(settle_s=0.6))
        cycles, landed = [], 0
        with UR5(config) as robot:
            for _ in range(args.picks):
                T = np.eye(4)
                T[:3, :3] = Rotation.from_euler("z", rng.uniform(0, 2 * np.pi)).as_matrix()
                T[:3, 3] = rng.uniform(*SIM_CELL.spawn_x), rng.uniform(*SIM_CELL.spawn_y), -box_min[2] + 0.002
                sim_cell.add("cup", asset.urdf_path, T)
                time.sleep(0.5 / args.time_scale)  # settles
                started = []
                outcome = attempt_pick(robot, sim_cell.pose("cup"), np.eye(4), target, SIM_CELL,
                                       moving=lambda: started.append(time.perf_counter()))
                if started:
                    cycles.append(time.perf_counter() - started[0])
                time.sleep(0.1)
                landed += sim_cell.in_basket("cup") and outcome.result == "picked"
                sim_cell.remove("cup")
    cycles = np.array(cycles)
    print(f"pick-and-place cycle at time scale {args.time_scale:g} (0.4 m/s, 1.5 m/s^2, 0.6 s gripper settle; "
          f"home to retreat): mean {cycles.mean():.2f} s, min {cycles.min():.2f} s, max {cycles.max():.2f} s over "
          f"{len(cycles)} attempts; {landed} of {args.picks} in the basket")


if __name__ == "__main__":
    main()

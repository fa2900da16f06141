"""Grasp planning (pure geometry) and pick-and-place of cup noodles through the real ur-rtde client and the
simulated controller: >= 19 of 20 picks land in the basket."""

import os
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pegasus_gen.assets.demo_library import build_demo_library
from pegasus_gen.assets.library import AssetLibrary
from robot_bridge.bridge import UR5, BridgeConfig, GripperConfig
from robot_bridge.grasp import plan_grasp
from robot_bridge.kinematics import fk
from robot_bridge.pick import pick_and_place
from robot_bridge.safety import SafetyEnvelope, UnsafeCommand
from robot_bridge.sim.process import SimControllerProcess
from robot_bridge.sim.world import HOME_Q

CUP_MIN, CUP_SIZE = np.array([-0.047, -0.047, -0.0525]), np.array([0.094, 0.094, 0.105])
BASKET = np.array([-0.15, -0.45, 0.0])


def camera_above(x=-0.45, y=0.0, z=0.8) -> np.ndarray:
    """T_base_cam of a camera looking straight down (OpenCV axes)."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("x", 180, degrees=True).as_matrix()
    T[:3, 3] = [x, y, z]
    return T


def pose(xyz, yaw=0.0, tilt_deg=0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("zx", [yaw, tilt_deg], degrees=[False, True]).as_matrix()
    T[:3, 3] = xyz
    return T


def test_upright_cup_is_grasped_across_its_axis_with_the_tool_down_at_the_nearest_yaw():
    T_base_cam, home = camera_above(), fk(HOME_Q)
    cup = pose([-0.45, 0.05, 0.0525], yaw=1.0)
    plan = plan_grasp(np.linalg.inv(T_base_cam) @ cup, T_base_cam, CUP_MIN, CUP_SIZE, BASKET[:2], 0.006, home,
                      axis=[0, 0, 1], envelope=SafetyEnvelope())
    for _, T in plan.waypoints():
        np.testing.assert_allclose(T[:3, 2], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(plan.grasp[:2, 3], [-0.45, 0.05], atol=1e-9)
    assert plan.grasp[2, 3] == pytest.approx(0.6 * 0.105)
    # symmetric: the jaws keep the tool's current closing direction, whatever the cup's yaw
    home_closing = np.r_[home[:2, 1], 0.0] / np.linalg.norm(home[:2, 1])
    np.testing.assert_allclose(plan.grasp[:3, 1], home_closing, atol=1e-9)
    assert plan.pre_grasp[2, 3] - plan.grasp[2, 3] == pytest.approx(0.12) and plan.width == pytest.approx(0.094)
    np.testing.assert_allclose(plan.place[:2, 3], BASKET[:2], atol=1e-12)


def test_a_box_is_grasped_across_its_narrow_side_and_too_wide_or_unsafe_grasps_are_refused():
    T_base_cam, home = camera_above(), fk(HOME_Q)
    box = pose([-0.4, 0.0, 0.03], yaw=0.3)
    plan = plan_grasp(np.linalg.inv(T_base_cam) @ box, T_base_cam, [-0.06, -0.02, -0.03], [0.12, 0.04, 0.06],
                      BASKET[:2], 0.006, home)
    closing = plan.grasp[:3, 1]
    assert abs(closing @ box[:3, 1]) == pytest.approx(1.0) and plan.width == pytest.approx(0.04)
    with pytest.raises(UnsafeCommand, match="wider than the gripper"):
        plan_grasp(np.linalg.inv(T_base_cam) @ box, T_base_cam, [-0.1, -0.1, -0.03], [0.2, 0.2, 0.06],
                   BASKET[:2], 0.006, home)
    with pytest.raises(UnsafeCommand, match="grasp waypoint"):
        plan_grasp(np.linalg.inv(T_base_cam) @ pose([-1.2, 0, 0.05]), T_base_cam, CUP_MIN, CUP_SIZE, BASKET[:2],
                   0.006, home, axis=[0, 0, 1], envelope=SafetyEnvelope())
    lying = pose([-0.4, 0.1, 0.047], yaw=0.5, tilt_deg=90)  # a cup on its side: across its axis, 9.4 cm
    plan = plan_grasp(np.linalg.inv(T_base_cam) @ lying, T_base_cam, CUP_MIN, CUP_SIZE, BASKET[:2], 0.006, home,
                      axis=[0, 0, 1])
    axis = lying[:3, 2]
    assert abs(plan.grasp[:3, 1] @ axis) < 1e-9


@pytest.fixture(scope="module")
def cup_urdf(tmp_path_factory):
    lib = AssetLibrary(tmp_path_factory.mktemp("lib"))
    build_demo_library(lib)
    return lib.get("noodle_cup_red").urdf_path


@pytest.mark.slow  # 55 s; the fast suite picks through the whole launch in tests/test_sim_grasp.py
def test_twenty_cup_picks_with_the_real_client_land_in_the_basket(cup_urdf):
    host = f"127.0.{os.getpid() % 200 + 20}.200"
    rng = np.random.default_rng(7)
    T_base_cam = camera_above()
    landed = 0
    with SimControllerProcess(host, time_scale=4.0) as sim:
        cell = sim.cell
        cell.set_basket(BASKET)
        config = BridgeConfig(host=host, speed=0.4, acceleration=1.5, gripper=GripperConfig(settle_s=0.2))
        with UR5(config) as robot:
            for attempt in range(20):
                x, y, yaw = rng.uniform(-0.55, -0.35), rng.uniform(-0.15, 0.15), rng.uniform(0, 2 * np.pi)
                T = np.eye(4)
                T[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
                T[:3, 3] = x, y, -CUP_MIN[2] + 0.002
                cell.add("cup", cup_urdf, T)
                time.sleep(0.15)  # settles (at 4x)
                # what pose estimation would report
                T_cam_obj = np.linalg.inv(T_base_cam) @ cell.pose("cup")
                plan = plan_grasp(T_cam_obj, T_base_cam, CUP_MIN, CUP_SIZE, BASKET[:2], 0.006, robot.tcp_pose(),
                                  axis=[0, 0, 1], envelope=config.envelope)
                result = pick_and_place(robot, plan)
                time.sleep(0.1)
                landed += cell.in_basket("cup") and bool(result.held)
                cell.remove("cup")
    print(f"picks in the basket: {landed} of 20")
    assert landed >= 19, landed

"""camera_node -> inference_node -> robot_node on the stand-in layer: a training image of the overfit
DOPE model, its ONNX export, and the simulated UR controller driven through ur-rtde; the robot ends at the
pre-grasp that the estimate and the hand-eye transform call for."""

import json
import os
import shutil
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dope_training.export import export_checkpoint
from dope_training.infer import DopeModel
from nodes import compat
from nodes.camera_node import CameraNode
from nodes.compat import Parameter
from nodes.inference_node import InferenceNode
from nodes.robot_node import RobotNode
from nodes.ros import REAL_ROS, latched, msgs
from pegasus_gen.geometry.cuboid import cuboid_points
from robot_bridge.bridge import UR5, BridgeConfig
from robot_bridge.cell import BASKET_CLEARANCE_M, SIM_CELL
from robot_bridge.grasp import plan_grasp
from robot_bridge.kinematics import fk
from robot_bridge.sim.process import SimControllerProcess
from robot_bridge.sim.world import HOME_Q
from robot_bridge.ur5_urdf import TCP_Z

pytestmark = pytest.mark.skipif(REAL_ROS, reason="runs the nodes on the stand-in layer")


def transform_to_matrix(msg) -> np.ndarray:
    """T [4, 4] of a TransformStamped, read independently of nodes.conversions."""
    r, t = msg.transform.rotation, msg.transform.translation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
    T[:3, 3] = [t.x, t.y, t.z]
    return T


def test_camera_inference_robot_chain_sends_the_robot_to_the_pregrasp(dope_dataset, overfit_dope, tmp_path):
    onnx_path, _ = export_checkpoint(overfit_dope / "last.pt", tmp_path / "model.onnx")
    scene = dope_dataset / "train_pbr" / "000000"
    camera = json.loads((scene / "scene_camera.json").read_text())["0"]
    K = np.array(camera["cam_K"]).reshape(3, 3)
    images = tmp_path / "images"
    images.mkdir()
    shutil.copy(scene / "rgb" / "000000.jpg", images / "000000.jpg")

    # the estimate the inference node will make, and a hand-eye transform that puts that cup in reach
    model = DopeModel(onnx_path)
    import cv2

    estimate = model.estimate(cv2.imread(str(images / "000000.jpg"))[..., ::-1].copy(), K)[0].T
    T_cam_world = np.eye(4)
    T_cam_world[:3, :3] = np.array(camera["cam_R_w2c"]).reshape(3, 3)
    T_cam_world[:3, 3] = np.array(camera["cam_t_w2c"]) / 1000
    T_world_cam = np.linalg.inv(T_cam_world)
    corners = cuboid_points(model.object.bbox_min, model.object.bbox_size) @ (T_world_cam @ estimate)[:3, :3].T \
        + (T_world_cam @ estimate)[:3, 3]
    T_base_world = np.eye(4)
    T_base_world[:3, 3] = [-0.45 - corners[8, 0], 0.0 - corners[8, 1], -corners[:8, 2].min()]
    T_base_cam = T_base_world @ T_world_cam
    tcp = np.eye(4)
    tcp[2, 3] = TCP_Z
    expected = plan_grasp(estimate, T_base_cam, model.object.bbox_min, model.object.bbox_size, SIM_CELL.basket[:2],
                          BASKET_CLEARANCE_M, fk(HOME_Q, tcp), axis=[0, 0, 1]).pre_grasp

    host = f"127.0.{os.getpid() % 200 + 20}.201"
    with SimControllerProcess(host, time_scale=2.0):
        compat.init()
        try:
            nodes = [
                CameraNode(parameter_overrides=[Parameter("folder", value=str(images)), Parameter("rate", value=2.0),
                                                Parameter("fx", value=K[0, 0]), Parameter("fy", value=K[1, 1]),
                                                Parameter("cx", value=K[0, 2]), Parameter("cy", value=K[1, 2])]),
                InferenceNode(parameter_overrides=[Parameter("model", value=str(onnx_path))]),
                RobotNode(parameter_overrides=[Parameter("host", value=host), Parameter("execute", value="pregrasp"),
                                               Parameter("hand_eye", value=T_base_cam.ravel().tolist()),
                                               Parameter("bbox_min", value=list(model.object.bbox_min)),
                                               Parameter("bbox_size", value=list(model.object.bbox_size))]),
            ]
            tf = {"/tf": [], "/tf_static": []}
            probe = compat.Node("tf_probe")
            for topic in tf:
                probe.create_subscription(msgs.TFMessage, topic, lambda m, t=topic: tf[t].extend(m.transforms),
                                          latched(1) if topic == "/tf_static" else 100)
            nodes.append(probe)
            executor = compat.MultiThreadedExecutor()
            for node in nodes:
                executor.add_node(node)
            t0 = time.monotonic()
            while not nodes[2].results and time.monotonic() - t0 < 60:
                executor.spin_once(timeout_sec=0.05)
            executor.shutdown()
            assert nodes[2].results[:1] == ["pregrasp"], nodes[2].results
            assert nodes[1].images >= 1
            # TF: the hand-eye as base_link -> camera (static), the estimate as camera -> noodle_cup_red_0
            (hand_eye,) = [t for t in tf["/tf_static"] if t.child_frame_id == "camera"]
            assert hand_eye.header.frame_id == "base_link"
            np.testing.assert_allclose(transform_to_matrix(hand_eye), T_base_cam, atol=1e-9)
            cup = [t for t in tf["/tf"] if t.child_frame_id == f"{model.object.name}_0"]
            assert cup and cup[0].header.frame_id == "camera"
            np.testing.assert_allclose(transform_to_matrix(cup[0]), estimate, atol=1e-6)
        finally:
            for node in nodes:
                node.destroy_node()
            compat.shutdown()
        with UR5(BridgeConfig(host=host)) as robot:
            reached = robot.tcp_pose()
    assert np.linalg.norm(reached[:3, 3] - expected[:3, 3]) < 1e-3
    assert np.degrees(Rotation.from_matrix(reached[:3, :3].T @ expected[:3, :3]).magnitude()) < 0.5

"""inference_node's refinements on the stand-in layer: the overfit DOPE model's ONNX export, a training frame's
image and rendered depth (32FC1) with one header stamp; it publishes DOPE's pose, the refined one (within
millimetres of the truth) and, on object_pose, the one ``use_pose`` picks; without depth support nothing
reaches object_pose. Without depth, the object's mesh lets it refine against the image."""

import time

import cv2
import numpy as np
import pytest

from dope_training.export import export_checkpoint
from nodes import compat
from nodes.compat import Parameter
from nodes.conversions import numpy_to_image, pose_msg_to_matrix
from nodes.inference_node import InferenceNode
from nodes.ros import REAL_ROS, Node, msgs
from pegasus_gen.errors import PegasusError
from pegasus_gen.formats.bop import bop_frames

pytestmark = pytest.mark.skipif(REAL_ROS, reason="runs the nodes on the stand-in layer")
TOPICS = ("object_pose", "object_pose_raw", "object_pose_refined")


def run_inference(onnx_path, frame, depth_m: np.ndarray | None, use_pose: str, **parameters) -> dict:
    """{topic: first PoseStamped received} after one image (+ depth when given) + camera_info, within 60 s."""
    compat.init()
    try:
        parameters = {"model": str(onnx_path), "refine": depth_m is not None, "use_pose": use_pose, **parameters}
        inference = InferenceNode(parameter_overrides=[Parameter(k, value=v) for k, v in parameters.items()])
        feeder = Node("feeder")
        image_pub = feeder.create_publisher(msgs.Image, "image", 5)
        depth_pub = feeder.create_publisher(msgs.Image, "depth", 5)
        info_pub = feeder.create_publisher(msgs.CameraInfo, "camera_info", 5)
        got = {}
        for topic in TOPICS:
            feeder.create_subscription(msgs.PoseStamped, topic, lambda m, t=topic: got.setdefault(t, m), 5)
        executor = compat.MultiThreadedExecutor()
        for node in (inference, feeder):
            executor.add_node(node)
        header = msgs.Header(frame_id="camera")
        header.stamp = feeder.get_clock().now().to_msg()
        image = cv2.imread(str(frame.image))[..., ::-1].copy()
        info = msgs.CameraInfo(header=header, height=image.shape[0], width=image.shape[1])
        info.k = frame.K.ravel().tolist()
        info_pub.publish(info)
        executor.spin_once(timeout_sec=0.1)
        if depth_m is not None:
            depth_pub.publish(numpy_to_image(depth_m.astype(np.float32), "32FC1", header))
        image_pub.publish(numpy_to_image(image, "rgb8", header))
        t0 = time.monotonic()
        while inference.images < 1 and time.monotonic() - t0 < 60:
            executor.spin_once(timeout_sec=0.05)
        for _ in range(20):  # deliver what it published
            executor.spin_once(timeout_sec=0.02)
        executor.shutdown()
        assert inference.images == 1
        return got
    finally:
        compat.shutdown()


def test_inference_node_publishes_raw_and_refined_poses(dope_dataset, overfit_dope, tmp_path):
    onnx_path, _ = export_checkpoint(overfit_dope / "last.pt", tmp_path / "model.onnx")
    frame = next(bop_frames(dope_dataset / "train_pbr"))
    truths = np.array([inst.T[:3, 3] for inst in frame.instances])

    got = run_inference(onnx_path, frame, frame.read_depth(), "refined")
    assert set(got) == set(TOPICS)
    refined = pose_msg_to_matrix(got["object_pose_refined"].pose)
    assert np.linalg.norm(truths - refined[:3, 3], axis=1).min() < 0.005
    np.testing.assert_allclose(pose_msg_to_matrix(got["object_pose"].pose), refined, atol=1e-9)

    got = run_inference(onnx_path, frame, np.zeros_like(frame.read_depth()), "refined")  # no depth support
    assert set(got) == {"object_pose_raw"}  # DOPE's pose is reported, the robot gets nothing

    got = run_inference(onnx_path, frame, np.zeros_like(frame.read_depth()), "raw")
    assert set(got) == {"object_pose", "object_pose_raw"}


def test_inference_node_refines_against_the_image_with_the_objects_mesh(dope_dataset, overfit_dope, tmp_path):
    onnx_path, _ = export_checkpoint(overfit_dope / "last.pt", tmp_path / "model.onnx")
    frame = next(bop_frames(dope_dataset / "train_pbr"))
    truths = np.array([inst.T[:3, 3] for inst in frame.instances])
    mesh = str(next((dope_dataset / "models").glob("obj_*.ply")))

    got = run_inference(onnx_path, frame, None, "refined", refine_rgb=mesh, mesh_scale=0.001)
    assert set(got) == set(TOPICS)
    raw, refined = (pose_msg_to_matrix(got[t].pose) for t in ("object_pose_raw", "object_pose_refined"))
    assert np.abs(refined - raw).max() > 1e-6  # moved by the image
    assert np.linalg.norm(truths - refined[:3, 3], axis=1).min() < 0.02  # on a cup
    np.testing.assert_allclose(pose_msg_to_matrix(got["object_pose"].pose), refined, atol=1e-9)

    compat.init()
    try:
        for overrides, refusal in (({"refine": True, "refine_rgb": mesh}, "choose one"),
                                   ({"use_pose": "refined"}, "refine_rgb mesh"),
                                   ({"refine_rgb": str(tmp_path / "none.ply")}, "cannot read the mesh"),
                                   ({"model": str(onnx_path), "zoom": str(tmp_path / "none.pt")},
                                    "no such zoom checkpoint")):
            with pytest.raises(PegasusError, match=refusal):
                InferenceNode(parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
    finally:
        compat.shutdown()

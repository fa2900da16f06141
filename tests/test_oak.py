"""The OAK camera path: the depthai 2 pipeline built with the real API (no device needed) and read back
from its serialised form; calibration, depth and stamp conversions; no device -> one clear line, exit 2."""

import datetime
import sys

import depthai as dai
import numpy as np
import pytest

from nodes.oak_camera import (
    STREAM,
    build_pipeline,
    calibration_intrinsics,
    depth_mm_to_metres,
    device_stamp_to_wall,
    isp_scale,
    rational_polynomial,
)
from pegasus_gen.cli.main import main
from pegasus_gen.errors import PegasusError


def graph(pipeline):
    """({node id: (node name, properties)}, {(from name.output, to name.input)}) of a depthai pipeline, from
    the JSON the device receives."""
    serialised = pipeline.serializeToJson()["pipeline"]
    nodes = {node_id: (node["name"], node["properties"]) for node_id, node in serialised["nodes"]}
    links = {(f"{nodes[c['node1Id']][0]}.{c['node1Output']}", f"{nodes[c['node2Id']][0]}.{c['node2Input']}")
             for c in serialised["connections"]}
    return nodes, links


def test_the_pipeline_aligns_stereo_depth_to_the_colour_frames_and_syncs_them():
    nodes, links = graph(build_pipeline(640, depth=True))
    by_name = {}
    for name, properties in nodes.values():
        by_name.setdefault(name, []).append(properties)
    assert sorted(by_name) == ["ColorCamera", "MonoCamera", "StereoDepth", "Sync", "XLinkOut"]
    colour = by_name["ColorCamera"][0]
    assert colour["boardSocket"] == int(dai.CameraBoardSocket.CAM_A)
    assert (colour["ispScale"]["horizNumerator"], colour["ispScale"]["horizDenominator"]) == (1, 3)
    assert sorted(m["boardSocket"] for m in by_name["MonoCamera"]) == [int(dai.CameraBoardSocket.CAM_B),
                                                                        int(dai.CameraBoardSocket.CAM_C)]
    stereo = by_name["StereoDepth"][0]
    assert stereo["depthAlignCamera"] == int(dai.CameraBoardSocket.CAM_A)
    assert (stereo["outWidth"], stereo["outHeight"]) == (640, 360)  # the colour frame's size
    assert by_name["XLinkOut"][0]["streamName"] == STREAM
    assert links == {("MonoCamera.out", "StereoDepth.left"), ("MonoCamera.out", "StereoDepth.right"),
                     ("ColorCamera.isp", "Sync.rgb"), ("StereoDepth.depth", "Sync.depth"),
                     ("Sync.out", "XLinkOut.in")}


def test_without_depth_the_colour_frames_go_out_alone():
    nodes, links = graph(build_pipeline(1280, depth=False))
    assert sorted(name for name, _ in nodes.values()) == ["ColorCamera", "XLinkOut"]
    assert links == {("ColorCamera.isp", "XLinkOut.in")}


def test_frame_sizes_are_the_ones_the_isp_can_make():
    assert [isp_scale(w) for w in (640, 960, 1280, 1920)] == [(1, 3, 360), (1, 2, 540), (2, 3, 720), (1, 1, 1080)]
    for width in (700, 2560, 600):
        with pytest.raises(PegasusError, match="cannot be"):
            isp_scale(width)


def test_calibration_gives_k_at_the_frame_size_and_rational_polynomial_distortion():
    calibration = dai.CalibrationHandler()
    K_full = np.array([[1500.0, 0.0, 962.0], [0.0, 1498.0, 541.0], [0.0, 0.0, 1.0]])
    coefficients = [0.5, -0.25, 0.001, -0.002, 0.125, 0.375, -0.0625, 0.03125] + [0.0] * 6
    calibration.setCameraIntrinsics(dai.CameraBoardSocket.CAM_A, K_full.tolist(), 1920, 1080)
    calibration.setDistortionCoefficients(dai.CameraBoardSocket.CAM_A, coefficients)
    K, distortion, dropped = calibration_intrinsics(calibration, 640, 360)
    np.testing.assert_allclose(K[:2], K_full[:2] / 3, rtol=1e-6)  # a third of the sensor's frame
    np.testing.assert_allclose(distortion, coefficients[:8], rtol=1e-6)
    assert dropped == 0.0
    assert rational_polynomial(list(range(14))) == [float(v) for v in range(8)]
    calibration.setDistortionCoefficients(dai.CameraBoardSocket.CAM_A, coefficients[:8] + [0.0, 0.01] + [0.0] * 4)
    assert calibration_intrinsics(calibration, 640, 360)[2] == pytest.approx(0.01)


def test_depth_and_stamp_conversions():
    depth = depth_mm_to_metres(np.array([[0, 1, 1000], [1234, 65535, 0]], dtype=np.uint16))
    assert depth.dtype == np.float32
    np.testing.assert_allclose(depth, [[0.0, 0.001, 1.0], [1.234, 65.535, 0.0]], rtol=1e-7)
    # a frame exposed 0.25 s before the clocks were read
    stamp = device_stamp_to_wall(datetime.timedelta(seconds=99.75), now_wall=1.7e9, now_monotonic=100.0)
    assert stamp == pytest.approx(1.7e9 - 0.25, abs=1e-6)


def test_without_depthai_the_message_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "depthai", None)  # import depthai fails
    with pytest.raises(PegasusError, match=r"pip install 'pegasus-stack\[oak\]'"):
        build_pipeline(640)


def test_without_a_device_the_launch_ends_with_one_clear_line(capsys):
    hand_eye = "[" + ", ".join(str(float(v)) for v in np.eye(4).ravel()) + "]"
    assert main(["launch", "ur5_pick_place.launch.py", "host:=127.0.0.1", "model:=none.onnx",
                 f"hand_eye:={hand_eye}", "source:=oak"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no OAK camera could be opened" in err[0] and "Traceback" not in err[0]

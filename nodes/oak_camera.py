"""The OAK camera through depthai 2 (``pip install 'pegasus-stack[oak]'``): colour from CAM_A and, optionally,
stereo depth from CAM_B/CAM_C aligned to it, synchronised on the device.

The colour stream is the 1080p sensor's ISP output scaled by ``width / 1920`` (no crop, so the
calibration's intrinsics scale with it); depth comes out of StereoDepth aligned to CAM_A at the same size.
The host keeps only the newest frame (output queue of size 1, non-blocking), stamps it with the middle of
its exposure on the host's wall clock, and reads the intrinsics and distortion from the device's
calibration (ROS ``rational_polynomial``). ``build_pipeline`` needs no device; ``OakCamera`` opens one.
"""

from __future__ import annotations

import datetime
import time
from fractions import Fraction

import numpy as np

from pegasus_gen.errors import PegasusError

SENSOR_SIZE = (1920, 1080)  # the colour sensor's 1080p mode, px
STREAM = "frames"  # the XLinkOut stream the host reads
SYNC_THRESHOLD = datetime.timedelta(milliseconds=20)  # colour and depth of one group at most this far apart


def _depthai():
    try:
        import depthai
    except ImportError:
        raise PegasusError("camera_node: source 'oak' needs depthai (pip install 'pegasus-stack[oak]')") from None
    return depthai


def isp_scale(width: int) -> tuple[int, int, int]:
    """(numerator, denominator, height) of the ISP scaling that makes the 1080p colour frame ``width`` px
    wide; PegasusError when the OAK's ISP cannot (numerator <= 16, denominator <= 63, whole heights)."""
    scale = Fraction(width, SENSOR_SIZE[0])
    height = SENSOR_SIZE[1] * scale
    if scale > 1 or scale.numerator > 16 or scale.denominator > 63 or height.denominator != 1 or width % 16:
        raise PegasusError(f"camera_node: an OAK colour frame cannot be {width} px wide; the sensor's 1920x1080 "
                           "scales to 640x360, 960x540, 1280x720 or 1920x1080 (width a multiple of 16)")
    return scale.numerator, scale.denominator, int(height)


def build_pipeline(width: int, depth: bool = True):
    """The device pipeline (``depthai.Pipeline``, built without a device): ColorCamera CAM_A (1080p, ISP
    scaled to ``width`` x ``width * 9 / 16``) and, with ``depth``, MonoCameras CAM_B/CAM_C (400p) into a
    StereoDepth (left-right check, subpixel, aligned to CAM_A at the colour size), both into a Sync node
    ("rgb", "depth"); its groups (or the colour frames alone) go out on the XLinkOut stream ``STREAM``."""
    dai = _depthai()
    num, den, height = isp_scale(width)
    pipeline = dai.Pipeline()
    colour = pipeline.create(dai.node.ColorCamera)
    colour.setBoardSocket(dai.CameraBoardSocket.CAM_A)
    colour.setResolution(dai.ColorCameraProperties.SensorResolution.THE_1080_P)
    colour.setIspScale(num, den)
    out = pipeline.create(dai.node.XLinkOut)
    out.setStreamName(STREAM)
    if not depth:
        colour.isp.link(out.input)
        return pipeline
    monos = []
    for socket in (dai.CameraBoardSocket.CAM_B, dai.CameraBoardSocket.CAM_C):
        mono = pipeline.create(dai.node.MonoCamera)
        mono.setBoardSocket(socket)
        mono.setResolution(dai.MonoCameraProperties.SensorResolution.THE_400_P)
        monos.append(mono)
    stereo = pipeline.create(dai.node.StereoDepth)
    stereo.setDefaultProfilePreset(dai.node.StereoDepth.PresetMode.DEFAULT)
    stereo.setLeftRightCheck(True)
    stereo.setSubpixel(True)
    stereo.setDepthAlign(dai.CameraBoardSocket.CAM_A)
    stereo.setOutputSize(width, height)
    monos[0].out.link(stereo.left)
    monos[1].out.link(stereo.right)
    sync = pipeline.create(dai.node.Sync)
    sync.setSyncThreshold(SYNC_THRESHOLD)
    colour.isp.link(sync.inputs["rgb"])
    stereo.depth.link(sync.inputs["depth"])
    sync.out.link(out.input)
    return pipeline


def depth_mm_to_metres(depth_mm: np.ndarray) -> np.ndarray:
    """StereoDepth's depth [H, W] uint16 mm (0 = none) -> float32 metres (0 = none)."""
    return depth_mm.astype(np.float32) / 1000.0


def rational_polynomial(coefficients) -> list[float]:
    """depthai's 14 distortion coefficients (k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4 tx ty, OpenCV's order) ->
    the 8 of ROS's ``rational_polynomial`` model (k1 k2 p1 p2 k3 k4 k5 k6); ROS has no model for the
    thin-prism and tilt terms (``OakCamera.dropped_distortion`` says how large they were)."""
    return ([float(c) for c in coefficients] + [0.0] * 8)[:8]


def calibration_intrinsics(calibration, width: int, height: int) -> tuple[np.ndarray, list[float], float]:
    """From a ``depthai.CalibrationHandler``: (K [3, 3] px of CAM_A's frames at ``width`` x ``height``, the
    rational_polynomial distortion [8], the largest thin-prism/tilt term it drops)."""
    import depthai as dai

    socket = dai.CameraBoardSocket.CAM_A
    K = np.array(calibration.getCameraIntrinsics(socket, width, height), dtype=np.float64)
    coefficients = calibration.getDistortionCoefficients(socket)
    return K, rational_polynomial(coefficients), max((abs(c) for c in coefficients[8:]), default=0.0)


def device_stamp_to_wall(stamp: datetime.timedelta, now_wall: float, now_monotonic: float) -> float:
    """A depthai timestamp (the host's steady clock, CLOCK_MONOTONIC, as a timedelta) -> seconds since the
    epoch, given the wall and monotonic clocks read at one moment."""
    return now_wall - now_monotonic + stamp.total_seconds()


class OakCamera:
    """An attached OAK running ``build_pipeline(width, depth)``: a camera_node source (``read``,
    ``intrinsics``, ``distortion``, ``distortion_model``; it never finishes)."""

    finished = False
    distortion_model = "rational_polynomial"

    def __init__(self, width: int, depth: bool = True):
        dai = _depthai()
        self.pipeline = build_pipeline(width, depth)
        self.width, self.height = width, isp_scale(width)[2]
        self.depth = depth
        try:
            self.device = dai.Device(self.pipeline)
        except RuntimeError as exc:
            raise PegasusError(f"camera_node: no OAK camera could be opened ({exc}); is one attached?") from None
        self.queue = self.device.getOutputQueue(STREAM, maxSize=1, blocking=False)  # the newest frame only
        self.K, self.distortion, self.dropped_distortion = calibration_intrinsics(
            self.device.readCalibration(), self.width, self.height)
        self.exposure_middle = dai.CameraExposureOffset.MIDDLE

    def read(self) -> tuple[np.ndarray, np.ndarray | None, float] | None:
        """(RGB [H, W, 3] uint8, depth [H, W] float32 m aligned to it or None, stamp s since the epoch at the
        middle of the exposure), or None when no new frame has arrived since the last call."""
        message = self.queue.tryGet()
        if message is None:
            return None
        frame = message["rgb"] if self.depth else message
        stamp = device_stamp_to_wall(frame.getTimestamp(self.exposure_middle), time.time(), time.monotonic())
        rgb = np.ascontiguousarray(frame.getCvFrame()[..., ::-1])
        depth = depth_mm_to_metres(message["depth"].getFrame()) if self.depth else None
        return rgb, depth, stamp

    def intrinsics(self, width: int, height: int) -> np.ndarray:
        """K [3, 3] (px) of the colour frames (their size is the pipeline's)."""
        return self.K

    def close(self) -> None:
        self.device.close()

import os
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from pegasus_gen.splats.cloud import SplatCloud


def random_cloud(rng: np.random.Generator, n: int, sh_degree: int = 3, labels=(0,), center=(0, 0, 0),
                 extent=0.5, scale_range=(0.01, 0.08), opacity_range=(0.2, 0.99)) -> SplatCloud:
    """n random anisotropic Gaussians with random SH in a cube of half-size ``extent`` around ``center``."""
    k = (sh_degree + 1) ** 2
    op = rng.uniform(*opacity_range, n)
    return SplatCloud(
        means=np.asarray(center) + rng.uniform(-extent, extent, size=(n, 3)),
        quats_wxyz=rng.normal(size=(n, 4)),
        log_scales=np.log(rng.uniform(*scale_range, size=(n, 3))),
        opacity_logits=np.log(op / (1 - op)),
        sh=np.concatenate([rng.normal(0, 0.8, size=(n, 1, 3)), rng.normal(0, 0.3, size=(n, k - 1, 3))], axis=1),
        labels=rng.choice(np.asarray(labels), n),
    )


def one_line_error(capsys):
    """The one error line of stderr (progress bars of generate, validate and view aside), and no traceback."""
    err = capsys.readouterr().err
    lines = [line for line in err.strip().splitlines() if not line.startswith(("generate:", "validate:", "view:"))]
    assert len(lines) == 1 and lines[0].startswith("pegasus: error: ") and "Traceback" not in err, err
    return lines[0]


def assert_covers_the_silhouette(splat_mask: np.ndarray, mesh_mask: np.ndarray, what: str) -> None:
    """A classic (not antialiased) splat render's mask [H, W] bool against the mesh's silhouette [H, W] bool: it
    covers the whole silhouette and overhangs its outline by about a pixel (the splats' low-pass). Measured on the
    demo objects and on boxes, cylinders and tori at 320x240: every mesh pixel covered, at most 3 % of the splats'
    pixels beyond one pixel of it, 0.2 % beyond two."""
    near = [cv2.dilate(mesh_mask.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8)) > 0 for r in (1, 2)]
    assert (splat_mask & mesh_mask).sum() >= 0.99 * mesh_mask.sum(), f"{what}: silhouette not covered"
    assert (splat_mask & ~near[0]).sum() <= 0.06 * splat_mask.sum(), f"{what}: more than a pixel beyond"
    assert (splat_mask & ~near[1]).sum() <= 0.01 * splat_mask.sum(), f"{what}: more than two pixels beyond"


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def library(tmp_path_factory):
    """The built-in demo library (8 objects, 3 environments), built once per test session; tests only read it."""
    from pegasus_gen.assets.demo_library import build_demo_library
    from pegasus_gen.assets.library import AssetLibrary

    lib = AssetLibrary(tmp_path_factory.mktemp("lib"))
    build_demo_library(lib)
    return lib


@pytest.fixture(scope="session")
def dope_dataset(request, tmp_path_factory):
    """A tiny BOP dataset for DOPE: 4 frames (320x240) of 3 red noodle cups seen from 0.28-0.32 m. Where
    PEGASUS_TEST_DOPE_DATASET names one made by this fixture elsewhere, that one (a GPU machine without pybullet
    runs the CUDA training test on a copy)."""
    if os.environ.get("PEGASUS_TEST_DOPE_DATASET"):
        return Path(os.environ["PEGASUS_TEST_DOPE_DATASET"])
    from pegasus_gen.dataset.config import load_config
    from pegasus_gen.dataset.generate import generate

    library = request.getfixturevalue("library")
    out = tmp_path_factory.mktemp("ds") / "ds"
    return generate(load_config(None, [f"output={out}", f"library={library.root}", "scenes=1", "frames_per_scene=4",
                                       "camera.width=320", "camera.height=240", "device=cpu",
                                       "environments=[wooden_table]", "objects=[{asset: 1, count: [1, 1]}]",
                                       "trajectory.distance=[0.28, 0.32]"]))


@pytest.fixture(scope="session")
def overfit_dope(dope_dataset, tmp_path_factory):
    """The light DOPE model without BatchNorm trained 500 steps (160 px crops, no augmentation) on
    ``dope_dataset``: its run folder (last.pt, loss.csv, ...). (With BatchNorm the same 500 steps leave one
    of the 4 training instances 5.7 cm off.)"""
    from dope_training.train import TrainConfig, train

    return train(TrainConfig(data=[str(dope_dataset)], object="noodle_cup_red",
                             out=str(tmp_path_factory.mktemp("overfit") / "run"), size=160, batch_size=4, epochs=500,
                             lr=1e-3, batch_norm=False, augment=False, loader_workers=0, device="cpu",
                             checkpoint_every=500))


@pytest.fixture(scope="session")
def zoom_run(dope_dataset, tmp_path_factory):
    """A zoom network for the noodle cups of ``dope_dataset`` (64 px crops), trained 12 epochs on 96 estimates
    drawn around each of its instances: its checkpoint."""
    from dope_training.zoom_config import ZoomConfig
    from dope_training.zoom_train import train_zoom

    out = tmp_path_factory.mktemp("zoom") / "zoom.pt"
    return train_zoom(ZoomConfig(data=[str(dope_dataset)], object="noodle_cup_red", out=str(out), epochs=12,
                                 per_instance=96, crop_px=64, object_px=44.0, rotation_std_deg=5.0, backgrounds=0.0,
                                 device="cpu", seed=0))


# -- the rclpy stand-in and real rclpy, side by side -------------------------------------------------------------
# rosidl's classes check their fields on assignment only with this set (read when a message module is first
# imported); nodes.ros sets it too, so real nodes are as strict as the stand-in.
os.environ.setdefault("ROS_PYTHON_CHECK_FIELDS", "1")
ROS_IMPLEMENTATIONS = ["stand-in", "rclpy"]


def ros_implementation(name: str):
    """The rclpy API and message classes of implementation ``name``: "stand-in" (nodes.compat, nodes.msgs) or
    "rclpy" (real rclpy over Fast DDS with rosidl's message classes, from the ros extra; the test is skipped
    where it is not installed). The tests that state rclpy's behaviour run on both, so that the stand-in cannot
    drift from the real thing unnoticed."""
    import importlib
    import types

    if name == "stand-in":
        from nodes import compat, msgs

        return types.SimpleNamespace(
            name=name, real=False, rclpy=compat, Node=compat.Node, Parameter=compat.Parameter,
            ParameterValue=compat.ParameterValue, ParameterDescriptor=compat.ParameterDescriptor,
            SingleThreadedExecutor=compat.SingleThreadedExecutor, MultiThreadedExecutor=compat.MultiThreadedExecutor,
            QoSProfile=compat.QoSProfile, ReliabilityPolicy=compat.ReliabilityPolicy,
            DurabilityPolicy=compat.DurabilityPolicy, exceptions=compat, RCLError=compat.RCLError,
            init=compat.init, message=msgs.message_class, Trigger=msgs.Trigger, serialize=msgs.serialize,
            deserialize=msgs.deserialize, other_context=lambda: compat.Context(graph=compat.context.default_context),
            settle=0.0)
    rclpy = pytest.importorskip("rclpy", reason="real rclpy comes with the ros extra (pip install '.[ros]')")
    from rcl_interfaces.msg import ParameterDescriptor, ParameterValue
    from rclpy import exceptions, serialization
    from rclpy._rclpy_pybind11 import RCLError
    from rclpy.context import Context
    from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_srvs.srv import Trigger

    def message(type_name):
        package, kind, short = type_name.split("/")
        return getattr(importlib.import_module(f"{package}.{kind}"), short)

    def init(args=None, context=None):
        # a DDS domain of this test process's own on this host only: parallel runs never meet
        os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        rclpy.init(args=args, context=context, domain_id=ROS_DOMAIN_ID)

    return types.SimpleNamespace(
        name=name, real=True, rclpy=rclpy, Node=Node, Parameter=Parameter, ParameterValue=ParameterValue,
        ParameterDescriptor=ParameterDescriptor, SingleThreadedExecutor=SingleThreadedExecutor,
        MultiThreadedExecutor=MultiThreadedExecutor, QoSProfile=QoSProfile, ReliabilityPolicy=ReliabilityPolicy,
        DurabilityPolicy=DurabilityPolicy, exceptions=exceptions, RCLError=RCLError, init=init, message=message,
        Trigger=Trigger, serialize=serialization.serialize_message,
        deserialize=lambda data, type_name: serialization.deserialize_message(data, message(type_name)),
        other_context=Context, settle=0.3)


# this process's DDS domain (0-101 are the ids whose ports never collide with ephemeral ones)
ROS_DOMAIN_ID = 1 + os.getpid() % 101


@pytest.fixture(params=ROS_IMPLEMENTATIONS)
def ros(request):
    """ros_implementation(...) of each implementation in turn."""
    return ros_implementation(request.param)


def spin_until(executor, done, timeout: float = 5.0, settle: float = 0.0) -> bool:
    """Spin ``executor`` until ``done()`` (then ``settle`` seconds more, for what should not arrive) or
    ``timeout`` seconds; whether ``done()``. Real DDS delivers after discovery, the stand-in at once."""
    t0 = time.monotonic()
    while not done() and time.monotonic() - t0 < timeout:
        executor.spin_once(timeout_sec=0.02)
    end = time.monotonic() + settle
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.02)
    return done()

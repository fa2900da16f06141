"""The ROS 2 package: package.xml as ROS 2's own parser (catkin_pkg) reads and validates it, and a real
colcon build (colcon-core, colcon-ros) of the source tree installs what ``ros2 run`` and ``ros2 launch``
look for: the ament index marker, package.xml and the launch files under share/pegasus, one executable per
node under lib/pegasus."""

from __future__ import annotations

import configparser
import importlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from catkin_pkg.package import parse_package

ROOT = Path(__file__).resolve().parents[1]
NODES = sorted(p.stem for p in (ROOT / "nodes").glob("*_node.py"))
ROS_DEPENDENCIES = {"rclpy", "sensor_msgs", "geometry_msgs", "vision_msgs", "std_srvs", "tf2_ros", "launch_ros"}


def test_package_xml_is_a_valid_format_3_ament_python_package():
    package = parse_package(str(ROOT / "package.xml"))
    package.validate()  # raises InvalidPackage on any violation of REP 149
    assert package.package_format == 3 and package.name == "pegasus" and package.get_build_type() == "ament_python"
    assert ROS_DEPENDENCIES <= {d.name for d in package.exec_depends}
    assert (ROOT / "resource" / package.name).is_file()


@pytest.fixture(scope="module")
def colcon_install(tmp_path_factory):
    """install/pegasus of ``colcon build`` on a copy of the source tree."""
    work = tmp_path_factory.mktemp("ws")
    shutil.copytree(ROOT, work / "src" / "pegasus", ignore=shutil.ignore_patterns(
        ".git", ".venv", "out", "build", "*.egg-info", "__pycache__", ".pytest_cache"))
    colcon = Path(sys.executable).parent / "colcon"
    result = subprocess.run([str(colcon), "build", "--event-handlers", "console_direct-"], cwd=work,
                            capture_output=True, text=True, env={**os.environ, "PYTHONWARNINGS": "ignore"})
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return work / "install" / "pegasus"


def test_colcon_build_installs_what_ros2_run_and_launch_find(colcon_install):
    marker = colcon_install / "share" / "ament_index" / "resource_index" / "packages" / "pegasus"
    assert marker.is_file()
    assert parse_package(str(colcon_install / "share" / "pegasus" / "package.xml")).name == "pegasus"
    launch_files = sorted(p.name for p in (colcon_install / "share" / "pegasus" / "launch").iterdir())
    assert launch_files == sorted(p.name for p in (ROOT / "launch").glob("*.launch.py"))
    for node in NODES:
        executable = colcon_install / "lib" / "pegasus" / node
        assert executable.is_file() and os.access(executable, os.X_OK), node
        assert f"'console_scripts', '{node}'" in executable.read_text()


def test_every_installed_entry_point_imports(colcon_install):
    (entry_points,) = colcon_install.glob("lib/python*/site-packages/*-info/entry_points.txt")
    parser = configparser.ConfigParser()
    parser.read(entry_points)
    scripts = dict(parser["console_scripts"])
    assert set(scripts) == {"pegasus", *NODES}
    for name, target in scripts.items():
        module, function = target.split(":")
        assert callable(getattr(importlib.import_module(module), function)), name
    assert all(scripts[node] == f"nodes.{node}:main" for node in NODES)

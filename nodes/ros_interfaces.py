"""The ROS 2 message packages the nodes use that ROS 2's wheels lack, built into this Python environment from
their definitions with the rosidl generators of the ``ros`` extra, as colcon builds an interface package:
tf2_msgs (TFMessage) and vision_msgs (the Detection3D types, version 4 as in Humble), from the definitions
``nodes.msgs`` holds. ``python -m nodes.ros_interfaces`` (make's set-up runs it); needs cmake and a C/C++
compiler, and does nothing where the packages import already (a ROS 2 install) or rclpy does not.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

import numpy

from nodes.msgs import EXTRA_DEFINITIONS

# package -> ({message: definition}, the packages its definitions use)
PACKAGES = {
    "tf2_msgs": ({"TFMessage": "geometry_msgs/TransformStamped[] transforms"}, ["geometry_msgs"]),
    "vision_msgs": ({name.split("/")[-1]: text for name, text in EXTRA_DEFINITIONS.items()
                     if name.startswith("vision_msgs/msg/")}, ["std_msgs", "geometry_msgs"]),
}

PACKAGE_XML = """<?xml version="1.0"?>
<package format="3">
  <name>{name}</name>
  <version>0.0.0</version>
  <description>{name}: the messages the PEGASUS nodes use, built by nodes.ros_interfaces</description>
  <maintainer email="maintainers@pegasus.invalid">PEGASUS stack maintainers</maintainer>
  <license>BSD-3-Clause</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
{depends}
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""

# The wheels' exported CMake targets name include folders of the machine that built them (its Python's and
# numpy's): in each imported target, a folder that does not exist here is replaced by this Python's or numpy's.
CMAKELISTS = """cmake_minimum_required(VERSION 3.21)
project({name})
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
{find}
find_package(Python3 REQUIRED COMPONENTS Interpreter Development)
function(use_this_python dir)
  get_directory_property(targets DIRECTORY ${{dir}} IMPORTED_TARGETS)
  foreach(t ${{targets}})
    get_target_property(inc ${{t}} INTERFACE_INCLUDE_DIRECTORIES)
    if(inc)
      set(fixed "")
      foreach(dir ${{inc}})
        if(EXISTS "${{dir}}" OR dir MATCHES "^[$]<")
          list(APPEND fixed "${{dir}}")
        elseif(dir MATCHES "numpy")
          list(APPEND fixed "${{NUMPY_INCLUDE}}")
        elseif(dir MATCHES "python3")
          list(APPEND fixed ${{Python3_INCLUDE_DIRS}})
        endif()
      endforeach()
      set_target_properties(${{t}} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${{fixed}}")
    endif()
  endforeach()
endfunction()
use_this_python(${{CMAKE_CURRENT_SOURCE_DIR}})
rosidl_generate_interfaces(${{PROJECT_NAME}} {files} DEPENDENCIES {deps})
ament_package()
"""


def write_package(name: str, root: Path) -> Path:
    """The interface package ``name``'s sources (package.xml, CMakeLists.txt, msg/*.msg) under ``root``."""
    messages, deps = PACKAGES[name]
    source = root / name
    (source / "msg").mkdir(parents=True)
    for message, text in messages.items():
        (source / "msg" / f"{message}.msg").write_text(text + "\n")
    (source / "package.xml").write_text(PACKAGE_XML.format(
        name=name, depends="\n".join(f"  <depend>{dep}</depend>" for dep in deps)))
    (source / "CMakeLists.txt").write_text(CMAKELISTS.format(
        name=name, find="\n".join(f"find_package({dep} REQUIRED)" for dep in deps),
        files=" ".join(f'"msg/{message}.msg"' for message in messages), deps=" ".join(deps)))
    return source


def build(name: str, prefix: Path, work: Path) -> None:
    """Generate, compile and install package ``name`` into ``prefix`` (libraries in lib/, which the wheels'
    bootstrapper puts on the library path; the Python package in site-packages)."""
    source = write_package(name, work / "src")
    build_dir = work / "build" / name
    build_dir.mkdir(parents=True)
    env = {**os.environ, "AMENT_PREFIX_PATH": str(prefix), "CMAKE_PREFIX_PATH": str(prefix),
           "PATH": f"{prefix / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}"}
    site = Path(sysconfig.get_paths()["purelib"]).relative_to(prefix)
    steps = [["cmake", str(source), f"-DCMAKE_INSTALL_PREFIX={prefix}", f"-DCMAKE_PREFIX_PATH={prefix}",
              f"-DPython3_EXECUTABLE={sys.executable}", f"-DNUMPY_INCLUDE={numpy.get_include()}",
              f"-DPYTHON_INSTALL_DIR={site}", "-DBUILD_TESTING=OFF", "-DCMAKE_BUILD_TYPE=Release"],
             ["cmake", "--build", ".", "--parallel", str(min(4, os.cpu_count() or 1))],
             ["cmake", "--install", "."]]
    for step in steps:
        result = subprocess.run(step, cwd=build_dir, env=env, capture_output=True, text=True)
        if result.returncode != 0:
            raise RuntimeError(f"ros_interfaces: building {name} failed at {' '.join(step[:2])}:\n"
                               f"{(result.stdout + result.stderr)[-4000:]}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m nodes.ros_interfaces", description=__doc__)
    parser.add_argument("--force", action="store_true", help="build even where the packages import already")
    args = parser.parse_args(argv)
    if importlib.util.find_spec("rclpy") is None:
        print("ros_interfaces: no rclpy here (pip install '.[ros]'): nothing to build")
        return 0
    wanted = [name for name in PACKAGES if args.force or importlib.util.find_spec(name) is None]
    if not wanted:
        return 0
    missing = [tool for tool in ("cmake", "c++", "cc") if shutil.which(tool) is None]
    if missing:
        print(f"ros_interfaces: {', '.join(missing)} not found: {', '.join(wanted)} not built (the nodes that "
              "need them run on the stand-in only)")
        return 0
    prefix = Path(sys.prefix)
    with tempfile.TemporaryDirectory(prefix="pegasus-rosidl-") as work:
        for name in wanted:
            build(name, prefix, Path(work))
            print(f"ros_interfaces: built {name} into {prefix}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

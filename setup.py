"""setuptools entry point that colcon's ament_python build runs; the metadata is in pyproject.toml. It adds
what a ROS 2 package installs besides its Python packages: the package marker, package.xml and the launch
files under share/, and the executables: ``pegasus`` and one per node (``ros2 run pegasus camera_node``;
colcon puts them in lib/pegasus through setup.cfg, pip on the PATH)."""

from glob import glob

from setuptools import setup

PACKAGE = "pegasus"
NODES = ("camera_node", "inference_node", "robot_node", "evaluator_node", "generator_node", "trainer_node",
         "sim_controller_node", "recorder_node")

setup(
    python_requires=">=3.10",
    data_files=[("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
                (f"share/{PACKAGE}", ["package.xml"]),
                (f"share/{PACKAGE}/launch", sorted(glob("launch/*.launch.py")))],
    entry_points={"console_scripts": ["pegasus = pegasus_gen.cli.main:main",
                                      *(f"{node} = nodes.{node}:main" for node in NODES)]},
)

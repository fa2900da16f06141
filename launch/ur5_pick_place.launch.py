"""Pick and place on a real UR5: an OAK camera (or an image folder), DOPE on ONNX, the robot node through
ur-rtde. Starts in dry-run mode: the robot node only logs what it would send until dry_run:=false.

pegasus launch launch/ur5_pick_place.launch.py host:=192.168.1.10 model:=MODEL.onnx \\
    hand_eye:="[r11, r12, r13, tx, r21, ..., 0.0, 0.0, 0.0, 1.0]" basket:="[-0.25, -0.28, 0.0]" [dry_run:=false]
hand_eye is T_base_cam (camera pose in the robot base frame, 16 numbers row-major, metres) from your
hand-eye calibration; basket is the basket floor centre in the base frame. Both are YAML lists of floats:
write every number with a decimal point (1.0, not 1), as launch_ros reads them as List[float].
Without a depth camera, refine_rgb:=MESH (the object's mesh in its model frame, mesh_scale:=0.001 for a model in
mm) use_pose:=refined moves the robot to the poses refined against the image (see inference_node). zoom:=ZOOM.pt (a
zoom network of the same object, pegasus train-zoom; several comma-separated, applied in turn) moves every pose by
its zoomed second look first.
"""

import typing

from nodes.launch_api import (
    DeclareLaunchArgument,
    LaunchConfiguration,
    LaunchDescription,
    Node,
    ParameterValue,
    Shutdown,
)
from robot_bridge.cell import SIM_CELL

List = typing.List  # launch_ros's value_type for a list parameter


def generate_launch_description():
    arg = LaunchConfiguration
    return LaunchDescription([
        DeclareLaunchArgument("host", description="the UR controller's address"),
        DeclareLaunchArgument("model", description="DOPE ONNX export"),
        DeclareLaunchArgument("hand_eye", description="T_base_cam, a YAML list of 16 floats, row-major"),
        DeclareLaunchArgument("basket", default_value=str(list(SIM_CELL.basket)),
                              description="basket floor centre, a YAML list of 3 floats (x, y, z)"),
        DeclareLaunchArgument("source", default_value="oak", choices=["oak", "folder"]),
        DeclareLaunchArgument("images", default_value="", description="image folder (source:=folder)"),
        DeclareLaunchArgument("execute", default_value="pregrasp", choices=["pregrasp", "pick"]),
        DeclareLaunchArgument("dry_run", default_value="true", choices=["true", "false"]),
        DeclareLaunchArgument("speed", default_value="0.1", description="TCP speed, m/s"),
        Node(package="pegasus", executable="camera_node", on_exit=Shutdown(), parameters=[{
            "source": arg("source"), "folder": arg("images"), "rate": 2.0}]),
        DeclareLaunchArgument("refine_rgb", default_value="",
                              description="the object's mesh: refine the poses against the image (empty: off)"),
        DeclareLaunchArgument("mesh_scale", default_value="1.0", description="metres per mesh unit"),
        DeclareLaunchArgument("zoom", default_value="",
                              description="zoom networks of the object, comma-separated: every pose moved by them "
                              "in turn (empty: off)"),
        DeclareLaunchArgument("use_pose", default_value="raw", choices=["raw", "refined"]),
        Node(package="pegasus", executable="inference_node", parameters=[{
            "model": arg("model"), "device": "auto", "refine_rgb": ParameterValue(arg("refine_rgb"), value_type=str),
            "mesh_scale": ParameterValue(arg("mesh_scale"), value_type=float), "use_pose": arg("use_pose"),
            "zoom": ParameterValue(arg("zoom"), value_type=str)}]),
        Node(package="pegasus", executable="robot_node", parameters=[{
            "host": arg("host"), "hand_eye": ParameterValue(arg("hand_eye"), value_type=List[float]),
            "basket": ParameterValue(arg("basket"), value_type=List[float]), "execute": arg("execute"),
            "dry_run": arg("dry_run"), "speed": ParameterValue(arg("speed"), value_type=float)}]),
    ])

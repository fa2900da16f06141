"""Closed-loop grasp evaluation in simulation: the simulated UR5 cell (PyBullet behind the simulated UR
controller) is the digital twin of a splat scene; a camera renders it from splats, DOPE estimates the
object's pose, the robot node picks through the real ur-rtde client, the evaluator counts.

pegasus launch launch/sim_pick_place.launch.py model:=MODEL.onnx [attempts:=20 objects:=a,b ...]
(or `pegasus sim-grasp`). The cell's layout (base, camera, basket, pick area) is ``robot_bridge.cell.SIM_CELL``;
the camera renders depth too, against which the inference node refines DOPE's poses (``use_pose``). With
``record:=NAME`` every topic goes into the rosbag2 bag NAME (MCAP).
"""

from nodes.launch_api import (
    DeclareLaunchArgument,
    LaunchConfiguration,
    LaunchConfigurationNotEquals,
    LaunchDescription,
    Node,
    ParameterValue,
    Shutdown,
)
from robot_bridge.cell import SIM_CELL

HAND_EYE = SIM_CELL.T_base_cam.ravel().tolist()


def generate_launch_description():
    arg = LaunchConfiguration
    return LaunchDescription([
        DeclareLaunchArgument("model", default_value="",
                              description="DOPE ONNX export (empty with pose_source:=ground_truth)"),
        DeclareLaunchArgument("pose_source", default_value="dope", choices=["dope", "ground_truth"]),
        DeclareLaunchArgument("use_pose", default_value="refined", choices=["raw", "refined"],
                              description="DOPE's pose as it is, or refined with the camera's depth"),
        DeclareLaunchArgument("objects", default_value="noodle_cup_red", description="asset names, comma-separated"),
        DeclareLaunchArgument("attempts", default_value="20"),
        DeclareLaunchArgument("environment", default_value="wooden_table"),
        DeclareLaunchArgument("library", default_value="", description="asset library (default: $PEGASUS_ASSETS)"),
        DeclareLaunchArgument("host", default_value="127.0.0.1", description="loopback address of the sim controller"),
        DeclareLaunchArgument("time_scale", default_value="1.0"),
        DeclareLaunchArgument("report", default_value="out/sim_grasp"),
        DeclareLaunchArgument("seed", default_value="0"),
        DeclareLaunchArgument("device", default_value="auto", choices=["auto", "cpu", "cuda"]),
        DeclareLaunchArgument("record", default_value="",
                              description="rosbag2 bag (MCAP) of every topic to create; empty: no recording"),
        Node(package="pegasus", executable="sim_controller_node", on_exit=Shutdown(), parameters=[{
            "host": arg("host"), "time_scale": ParameterValue(arg("time_scale"), value_type=float),
            "basket": list(SIM_CELL.basket)}]),
        Node(package="pegasus", executable="camera_node", parameters=[{
            "source": "sim", "host": arg("host"), "library": arg("library"), "environment": arg("environment"),
            "T_world_base": SIM_CELL.T_world_base.ravel().tolist(),
            "T_world_cam": SIM_CELL.T_world_cam.ravel().tolist(),
            "width": SIM_CELL.camera_size[0], "height": SIM_CELL.camera_size[1], "fx": SIM_CELL.camera_fx,
            "rate": 2.0, "device": arg("device")}]),
        Node(package="pegasus", executable="inference_node", parameters=[{
            "model": arg("model"), "refine": True, "use_pose": arg("use_pose")}]),
        Node(package="pegasus", executable="robot_node", parameters=[{
            "host": arg("host"), "hand_eye": HAND_EYE, "basket": list(SIM_CELL.basket), "table_z": SIM_CELL.table_z,
            "home": list(SIM_CELL.home), "wait_for_attempt": True, "speed": 0.3}]),
        Node(package="pegasus", executable="evaluator_node", on_exit=Shutdown(), parameters=[{
            "host": arg("host"), "library": arg("library"), "objects": ParameterValue(arg("objects"), value_type=str),
            "attempts": arg("attempts"),
            "seed": arg("seed"), "hand_eye": HAND_EYE, "spawn_x": list(SIM_CELL.spawn_x),
            "spawn_y": list(SIM_CELL.spawn_y), "report": arg("report"),
            "pose_source": arg("pose_source")}]),
        Node(package="pegasus", executable="recorder_node", condition=LaunchConfigurationNotEquals("record", ""),
             parameters=[{"path": ParameterValue(arg("record"), value_type=str)}]),
    ])

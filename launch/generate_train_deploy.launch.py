"""Generate a dataset, train DOPE on it, and run inference on camera images with the new model.

pegasus launch launch/generate_train_deploy.launch.py object:=noodle_cup_red images:=DIR [scenes:=4 ...]
(ros2 launch works too where ROS 2 and this package are installed.)
"""

from nodes.launch_api import (
    DeclareLaunchArgument,
    LaunchConfiguration,
    LaunchDescription,
    Node,
    ParameterValue,
    Shutdown,
)


def generate_launch_description():
    arg = LaunchConfiguration
    return LaunchDescription([
        DeclareLaunchArgument("object", default_value="noodle_cup_red", description="object to train for"),
        DeclareLaunchArgument("output", default_value="out/loop/dataset", description="dataset folder"),
        DeclareLaunchArgument("run", default_value="out/loop/run", description="training output folder"),
        DeclareLaunchArgument("config", default_value="", description="generation config YAML (default: built-in)"),
        DeclareLaunchArgument("scenes", default_value="4"),
        DeclareLaunchArgument("library", default_value="", description="asset library (default: $PEGASUS_ASSETS)"),
        DeclareLaunchArgument("environments", default_value="", description="YAML list (default: the config's)"),
        DeclareLaunchArgument("objects_config", default_value="", description="YAML list of {asset, count}"),
        DeclareLaunchArgument("frames", default_value="10", description="frames per scene"),
        DeclareLaunchArgument("width", default_value="320"),
        DeclareLaunchArgument("height", default_value="240"),
        DeclareLaunchArgument("epochs", default_value="5"),
        DeclareLaunchArgument("size", default_value="0", description="training crop, px (0: the variant's)"),
        DeclareLaunchArgument("train_options", default_value="",
                              description="more training settings: key=value ... (pegasus train's, e.g. focal_px=330)"),
        DeclareLaunchArgument("variant", default_value="light", choices=["light", "full", "pretrained"]),
        DeclareLaunchArgument("device", default_value="auto", choices=["auto", "cpu", "cuda"]),
        DeclareLaunchArgument("images", default_value="out/loop/dataset/train_pbr/000000/rgb",
                              description="images the camera node plays"),
        DeclareLaunchArgument("max_images", default_value="0", description="> 0: stop after this many inferences"),
        Node(package="pegasus", executable="generator_node", on_exit=Shutdown(), parameters=[{
            "config": arg("config"), "output": arg("output"), "scenes": arg("scenes"),
            "frames_per_scene": arg("frames"), "width": arg("width"), "height": arg("height"), "device": arg("device"),
            "library": arg("library"), "environments": ParameterValue(arg("environments"), value_type=str),
            "objects": ParameterValue(arg("objects_config"), value_type=str)}]),
        Node(package="pegasus", executable="trainer_node", on_exit=Shutdown(), parameters=[{
            "object": arg("object"), "out": arg("run"), "variant": arg("variant"), "epochs": arg("epochs"),
            "size": arg("size"), "device": arg("device"),
            "options": ParameterValue(arg("train_options"), value_type=str)}]),
        Node(package="pegasus", executable="camera_node", parameters=[{"folder": arg("images"), "rate": 1.0,
                                                                        "wait_for_folder": True}]),
        Node(package="pegasus", executable="inference_node", on_exit=Shutdown(), parameters=[{"device": "cpu",
                                                                           "max_images": arg("max_images")}]),
    ])

"""What a launch file imports: ROS 2's own launch API (``launch``, ``launch_ros``) where it is installed, else
this project's stand-in for the subset the launch files use (``nodes.launch``)."""

try:
    from launch.actions import DeclareLaunchArgument, Shutdown
    from launch.conditions import LaunchConfigurationNotEquals
    from launch.substitutions import LaunchConfiguration
    from launch_ros.actions import Node
    from launch_ros.parameter_descriptions import ParameterValue

    from launch import LaunchDescription
except ImportError:
    from nodes.launch import (
        DeclareLaunchArgument,
        LaunchConfiguration,
        LaunchConfigurationNotEquals,
        LaunchDescription,
        Node,
        ParameterValue,
        Shutdown,
    )

__all__ = ["DeclareLaunchArgument", "LaunchConfiguration", "LaunchConfigurationNotEquals", "LaunchDescription", "Node",
           "ParameterValue", "Shutdown"]

"""The ROS 2 nodes (generator, trainer, camera, inference, robot, evaluator, sim controller), the launch-file
runner and the demo loop, written against ``nodes.ros``: the real rclpy when installed, else the stand-in."""

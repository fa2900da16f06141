"""ROS 2-style nodes and the rclpy-compatible layer: ``nodes.ros`` gives the real rclpy and ROS 2
messages when installed, else the stand-in (``nodes.compat``, ``nodes.msgs``)."""

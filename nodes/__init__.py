"""ROS 2-style nodes and the rclpy-compatible layer (built in a later milestone)."""

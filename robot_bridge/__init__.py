"""The UR5 side: kinematics, the safety envelope, the ur-rtde bridge, grasp planning, pick-and-place and
grasp-attempt scoring; ``robot_bridge.sim`` is the simulated UR controller that the ur-rtde client drives."""

"""The simulated UR controller: a PyBullet UR5 cell behind the real controller's dashboard, RTDE and script
ports, so the unmodified ur-rtde client drives it (``python -m robot_bridge.sim`` or ``pegasus sim-robot``)."""

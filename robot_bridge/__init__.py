"""UR5 bridge over ur-rtde and a simulated UR controller (built in a later milestone)."""

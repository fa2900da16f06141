"""UR5 bridge: kinematics from the DH table (here now); the ur-rtde client wrapper, the simulated UR
controller, grasp planning and the safety envelope follow."""

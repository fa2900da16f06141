"""UR5 bridge: kinematics from the DH table, the safety envelope, a robot interface over ur-rtde
(``bridge.UR5``), grasp planning and pick-and-place, and a simulated UR controller in front of a PyBullet UR5
cell (``sim``) that the unmodified ur-rtde client drives."""

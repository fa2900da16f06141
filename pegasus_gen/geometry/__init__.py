"""Camera and object geometry: pinhole intrinsics, look-at poses, orbit trajectories, DOPE's cuboid, pose errors
(ADD / ADD-S). numpy and scipy only; imports nothing above errors."""

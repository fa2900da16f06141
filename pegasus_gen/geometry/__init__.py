"""Camera and object geometry: pinhole intrinsics, look-at poses, orbit trajectories, DOPE's cuboid.
Plain numpy; imports nothing above errors."""

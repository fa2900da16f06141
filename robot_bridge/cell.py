"""The pick-and-place cell's layout, defined once: where the robot's base, the camera, the basket and the
pick area are. The simulated cell's launch file, the nodes' defaults, the grasp benchmark and the demo read it.

``SIM_CELL``: the environment's table top is the world's z = 0; the robot's base stands on it at world
(0.45, 0, 0) with the world's axes (so it faces -x, where objects appear, base x -0.55..-0.38 and y
-0.12..0.12); the basket's floor centre is at base (-0.25, -0.28, 0); the camera looks from world
(0, -0.35, 0.55) at the world origin, 640x480 with a 60 degree horizontal field of view (fx 554 px), 0.55-0.8 m
from the pick area at 45-65 degrees of elevation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pegasus_gen.geometry.cameras import look_at

HOME_Q = (0.0, -1.8, 1.8, -1.57, -1.57, 0.0)  # rad: the TCP pointing down in front of the base
BASKET_CLEARANCE_M = 0.006  # the object's lowest point above the basket's floor when the gripper lets it go


@dataclass(frozen=True)
class CellLayout:
    """A cell's layout (m, rad): the base's position in the world (base axes = world axes), the camera's eye
    and target in the world, its image size (px) and horizontal field of view (degrees), the basket's floor
    centre and the pick area (x, y ranges) in the base frame, the table top's height in the base frame, the
    arm's home joints."""

    base_in_world: tuple[float, float, float]
    camera_eye: tuple[float, float, float]
    camera_target: tuple[float, float, float]
    camera_size: tuple[int, int]
    camera_fov_deg: float
    basket: tuple[float, float, float]
    spawn_x: tuple[float, float]
    spawn_y: tuple[float, float]
    table_z: float = 0.0
    home: tuple[float, ...] = HOME_Q

    @property
    def T_world_base(self) -> np.ndarray:
        """[4, 4] the robot's base in the world."""
        T = np.eye(4)
        T[:3, 3] = self.base_in_world
        return T

    @property
    def T_world_cam(self) -> np.ndarray:
        """[4, 4] the camera (OpenCV axes) in the world."""
        return np.linalg.inv(look_at(list(self.camera_eye), list(self.camera_target)))

    @property
    def T_base_cam(self) -> np.ndarray:
        """[4, 4] the hand-eye transform: the camera in the base frame."""
        return np.linalg.inv(self.T_world_base) @ self.T_world_cam

    @property
    def camera_fx(self) -> float:
        """The camera's focal length (px) from its width and field of view."""
        return (self.camera_size[0] / 2) / float(np.tan(np.radians(self.camera_fov_deg / 2)))


SIM_CELL = CellLayout(base_in_world=(0.45, 0.0, 0.0), camera_eye=(0.0, -0.35, 0.55),
                      camera_target=(0.0, 0.0, 0.0), camera_size=(640, 480), camera_fov_deg=60.0,
                      basket=(-0.25, -0.28, 0.0), spawn_x=(-0.55, -0.38), spawn_y=(-0.12, 0.12))

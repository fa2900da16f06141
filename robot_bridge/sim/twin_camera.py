"""The simulated cell's camera: the digital twin of its physics rendered from splats. Each frame is the
environment plus every body of the cell at the pose the simulated controller reports (its PyBullet state),
each drawn with the splats of its asset (``client.body_asset``)."""

from __future__ import annotations

import numpy as np

from robot_bridge.sim.client import SimCell, body_asset


class TwinCamera:
    """A camera source (as ``nodes.camera_node`` reads them) of the cell at ``host``: the asset ``library``'s
    ``environment`` and objects, the robot's base at T_world_base and the camera at T_world_cam (16 numbers
    row-major or [4, 4] each, m), ``width`` x ``height`` px with intrinsics K [3, 3], rendered on ``device``."""

    finished, distortion, distortion_model = False, None, "plumb_bob"

    def __init__(self, host: str, library: str, environment: str, T_world_base, T_world_cam, width: int,
                 height: int, K: np.ndarray, device: str):
        from pegasus_gen.assets.library import AssetLibrary

        self.cell = SimCell(host)
        self.library = AssetLibrary(library or None)
        self.environment = self.library.get(environment).splats.with_label(0)
        self.T_world_base = np.array(T_world_base, dtype=np.float64).reshape(4, 4)
        self.T_cam_world = np.linalg.inv(np.array(T_world_cam, dtype=np.float64).reshape(4, 4))
        self.width, self.height, self.K, self.device = width, height, K, device
        self.splats = {}

    def object_poses(self) -> dict[str, np.ndarray]:
        """{body name: T_world_obj [4, 4]} of the cell's bodies now."""
        poses = {}
        for name in self.cell.names():
            try:
                poses[name] = self.T_world_base @ self.cell.pose(name)
            except LookupError:  # removed (by the evaluator) since the listing
                continue
        return poses

    def read(self) -> tuple[np.ndarray, np.ndarray, None]:
        """The cell as the camera sees it: RGB [H, W, 3] uint8, depth [H, W] float32 metres (0 = none), no
        stamp (rendered now)."""
        from pegasus_gen.io.images import rgb_to_uint8
        from pegasus_gen.render.renderer import render

        parts = [self.environment]
        for k, (name, T) in enumerate(self.object_poses().items()):
            asset = body_asset(name)
            if asset not in self.splats:
                self.splats[asset] = self.library.get(asset).splats
            parts.append(self.splats[asset].transformed(T).with_label(k + 1))
        out = render(parts, self.K, self.T_cam_world, self.width, self.height, device=self.device)
        return rgb_to_uint8(out.rgb), np.nan_to_num(out.depth, nan=0.0, posinf=0.0).astype(np.float32), None

    def intrinsics(self, width: int, height: int):
        return self.K

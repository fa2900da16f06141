"""Pictures of assets: a turntable of splat renders above the collision mesh's silhouettes."""

from __future__ import annotations

import numpy as np

from pegasus_gen.assets.library import Asset
from pegasus_gen.geometry.cameras import intrinsics_from_fov, look_at
from pegasus_gen.io.images import rgb_to_uint8
from pegasus_gen.render.renderer import render
from pegasus_gen.render.silhouette import mesh_silhouette


def turntable(asset: Asset, views: int = 6, width: int = 240, height: int = 180, elevation_deg: float = 30.0,
              device: str = "auto") -> tuple[np.ndarray, list[float]]:
    """(image [2*height, views*width, 3] uint8, IoU per view) of ``asset`` seen from a circle of cameras.

    Top row: splat renders on grey. Bottom row: the collision-mesh silhouette (white) with the splat
    alpha > 0.5 mask outline where they differ (red: splats only, blue: mesh only).
    """
    lo, hi = asset.mesh.bounds
    centre = (lo + hi) / 2
    radius = np.linalg.norm(hi - lo) / 2
    K = intrinsics_from_fov(width, height, 40.0)
    distance = 1.25 * radius / np.sin(np.radians(15.0))
    el = np.radians(elevation_deg)
    top, bottom, ious = [], [], []
    for i in range(views):
        az = 2 * np.pi * i / views
        eye = centre + distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        T = look_at(eye, centre)
        out = render(asset.splats, K, T, width, height, background=(0.5, 0.5, 0.5), device=device)
        splat_mask = out.alpha > 0.5
        mesh_mask = mesh_silhouette(asset.mesh.vertices, asset.mesh.faces, K, T, width, height)
        union = (splat_mask | mesh_mask).sum()
        ious.append(float((splat_mask & mesh_mask).sum() / union) if union else 1.0)
        sil = np.zeros((height, width, 3), np.uint8)
        sil[mesh_mask & splat_mask] = 255
        sil[splat_mask & ~mesh_mask] = (230, 40, 40)
        sil[mesh_mask & ~splat_mask] = (40, 80, 230)
        top.append(rgb_to_uint8(out.rgb))
        bottom.append(sil)
    return np.concatenate([np.concatenate(top, 1), np.concatenate(bottom, 1)], 0), ious

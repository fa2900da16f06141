"""Camera models and poses (OpenCV pinhole: x right, y down, z forward; K in pixels)."""

from __future__ import annotations

from typing import Callable

import numpy as np


def intrinsics_from_fov(width: int, height: int, fov_x_deg: float) -> np.ndarray:
    """K [3, 3] for a horizontal field of view (degrees), square pixels, principal point at the centre.

    With pixel centres at integer coordinates the image centre is ((W-1)/2, (H-1)/2).
    """
    fx = 0.5 * width / np.tan(np.radians(fov_x_deg) / 2)
    return np.array([[fx, 0.0, (width - 1) / 2], [0.0, fx, (height - 1) / 2], [0.0, 0.0, 1.0]])


def intrinsics(width: int, height: int, fov_x_deg: float, fx: float | None = None, fy: float | None = None,
               cx: float | None = None, cy: float | None = None) -> np.ndarray:
    """K [3, 3]: from the horizontal field of view unless ``fx`` is given (``fy`` defaults to ``fx``);
    the principal point defaults to the image centre."""
    K = intrinsics_from_fov(width, height, fov_x_deg)
    if fx is not None:
        K[0, 0] = fx
        K[1, 1] = fy if fy is not None else fx
    if cx is not None:
        K[0, 2] = cx
    if cy is not None:
        K[1, 2] = cy
    return K


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """T_cam_world [4, 4] for a camera at ``eye`` looking at ``target`` (world points, metres).

    The image's up direction is as close to ``up`` as possible (camera -y along ``up``).
    """
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    if np.linalg.norm(z) == 0:
        raise ValueError("look_at: eye and target coincide")
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(x) < 1e-9:  # looking along up: pick any perpendicular
        x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R_world_cam = np.stack([x, y, z], axis=1)
    T = np.eye(4)
    T[:3, :3] = R_world_cam.T
    T[:3, 3] = -R_world_cam.T @ eye
    return T


def frame_points(points: np.ndarray, K: np.ndarray, width: int, height: int, azimuth_deg: float = -60.0,
                 elevation_deg: float = 35.0, margin: float = 1.15) -> np.ndarray:
    """T_cam_world of a camera on a sphere around ``points`` [N, 3] that keeps their bulk in view.

    Uses the 2nd..98th percentile box so stray splats do not shrink the view.
    """
    lo, hi = np.percentile(points, [2, 98], axis=0)
    center = (lo + hi) / 2
    radius = max(np.linalg.norm(hi - lo) / 2, 1e-3)
    half_fov = min(np.arctan(0.5 * width / K[0, 0]), np.arctan(0.5 * height / K[1, 1]))
    distance = margin * radius / np.sin(half_fov)
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    eye = center + distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return look_at(eye, center)


def orbit_key_poses(target: np.ndarray, rng: np.random.Generator, count: int,
                    distance: tuple[float, float] = (0.4, 0.8), elevation_deg: tuple[float, float] = (20.0, 70.0),
                    azimuth_span_deg: float = 360.0, jitter: float = 0.02,
                    score: Callable[[np.ndarray], float] | None = None, min_score: float = 1.0,
                    tries: int = 30, redraw_azimuth: bool = False) -> list[np.ndarray]:
    """``count`` random T_cam_world key poses on a spherical shell around ``target`` [3] (world, m),
    each looking at the target (plus up to ``jitter`` m of random aim offset), z up in the image.

    Azimuths advance in order over ``azimuth_span_deg`` so interpolated trajectories sweep around.
    With ``score`` (T_cam_world -> float), distance, elevation and aim are redrawn up to ``tries`` times
    per key pose until the score reaches ``min_score``; the best draw is kept. With ``redraw_azimuth`` each try
    also draws its azimuth anew within the key pose's share of the span (the order kept).
    """
    start = rng.uniform(0, 2 * np.pi)
    azimuths = start + np.sort(rng.uniform(0, np.radians(azimuth_span_deg), count))
    share = np.radians(azimuth_span_deg) / count
    poses = []
    for k, az in enumerate(azimuths):
        best, best_score = None, -np.inf
        for _ in range(tries if score is not None else 1):
            if redraw_azimuth:
                az = start + share * (k + rng.uniform())
            d = rng.uniform(*distance)
            el = np.radians(rng.uniform(*elevation_deg))
            eye = np.asarray(target) + d * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
            T = look_at(eye, np.asarray(target) + rng.uniform(-jitter, jitter, 3))
            s = score(T) if score is not None else 0.0
            if s > best_score:
                best, best_score = T, s
            if s >= min_score:
                break
        poses.append(best)
    return poses


def interpolate_poses(key_poses: list[np.ndarray], frames: int) -> list[np.ndarray]:
    """``frames`` T_cam_world [4, 4] along the key poses: camera centres linearly, orientations by SLERP,
    with the key poses at evenly spaced frames (first and last included)."""
    from scipy.spatial.transform import Rotation, Slerp

    if len(key_poses) == 1 or frames == 1:
        return [np.array(key_poses[0], dtype=np.float64) for _ in range(frames)]
    keys = np.linspace(0.0, 1.0, len(key_poses))
    R_world_cam = Rotation.from_matrix([np.asarray(T)[:3, :3].T for T in key_poses])
    centres = np.array([-np.asarray(T)[:3, :3].T @ np.asarray(T)[:3, 3] for T in key_poses])
    times = np.linspace(0.0, 1.0, frames)
    rotations = Slerp(keys, R_world_cam)(times).as_matrix()
    out = []
    for t, R_wc in zip(times, rotations):
        centre = np.array([np.interp(t, keys, centres[:, k]) for k in range(3)])
        T = np.eye(4)
        T[:3, :3] = R_wc.T
        T[:3, 3] = -R_wc.T @ centre
        out.append(T)
    return out

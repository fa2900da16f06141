"""Procedural splat scenes: textured surfaces covered with flat Gaussians (demo, tests, benchmarks).

Every function takes a ``numpy.random.Generator`` and returns a :class:`SplatCloud` in metres.
"""

from __future__ import annotations

import numpy as np

from pegasus_gen.splats.cloud import SplatCloud
from pegasus_gen.splats.surface_splats import surface_splats


def wood_texture(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Procedural wood grain, rgb [N, 3] in [0, 1], for surface coordinates u, v in metres."""
    rings = np.sin(40.0 * u + 3.0 * np.sin(7.0 * v) + 1.5 * np.sin(23.0 * v + 2.0 * u))
    t = 0.5 + 0.5 * rings
    light = np.array([0.78, 0.58, 0.36])
    dark = np.array([0.52, 0.33, 0.17])
    return light * (1 - t[:, None]) + dark * t[:, None]


def plane(size_x: float, size_y: float, n: int, texture, rng: np.random.Generator, z: float = 0.0,
          **kwargs) -> SplatCloud:
    """A jittered grid of ~n splats on the rectangle |x| <= size_x/2, |y| <= size_y/2 at height z, normal +z."""
    ratio = size_x / size_y
    ny = max(1, int(round(np.sqrt(n / ratio))))
    nx = max(1, int(round(n / ny)))
    spacing = size_x / nx
    gx, gy = np.meshgrid((np.arange(nx) + 0.5) / nx - 0.5, (np.arange(ny) + 0.5) / ny - 0.5)
    xy = np.stack([gx.ravel() * size_x, gy.ravel() * size_y], axis=1)
    xy += rng.uniform(-0.3, 0.3, size=xy.shape) * spacing
    pts = np.concatenate([xy, np.full((len(xy), 1), z)], axis=1)
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    return surface_splats(pts, normals, texture(xy[:, 0], xy[:, 1]), spacing, rng, **kwargs)


def cylinder(radius: float, height: float, n: int, side_texture, top_color, rng: np.random.Generator,
             **kwargs) -> SplatCloud:
    """A closed cylinder (cup-like), axis z, centred at the origin; side_texture(angle, z) -> rgb."""
    side_area = 2 * np.pi * radius * height
    cap_area = np.pi * radius**2
    n_side = int(n * side_area / (side_area + 2 * cap_area))
    n_cap = (n - n_side) // 2
    spacing = np.sqrt((side_area + 2 * cap_area) / max(n, 1))
    ang = rng.uniform(0, 2 * np.pi, n_side)
    zs = rng.uniform(-height / 2, height / 2, n_side)
    side = np.stack([radius * np.cos(ang), radius * np.sin(ang), zs], axis=1)
    side_n = np.stack([np.cos(ang), np.sin(ang), np.zeros(n_side)], axis=1)
    r = radius * np.sqrt(rng.uniform(0, 1, 2 * n_cap))
    a = rng.uniform(0, 2 * np.pi, 2 * n_cap)
    sign = np.repeat([1.0, -1.0], n_cap)
    caps = np.stack([r * np.cos(a), r * np.sin(a), sign * height / 2], axis=1)
    caps_n = np.stack([np.zeros(2 * n_cap), np.zeros(2 * n_cap), sign], axis=1)
    colors = np.concatenate([side_texture(ang, zs), np.tile(np.asarray(top_color, float), (2 * n_cap, 1))])
    return surface_splats(np.concatenate([side, caps]), np.concatenate([side_n, caps_n]), colors, spacing,
                          rng, **kwargs)


def box(size, n: int, colors_per_face, rng: np.random.Generator, **kwargs) -> SplatCloud:
    """An axis-aligned box of ``size`` (sx, sy, sz) centred at the origin; one rgb per face (6)."""
    size = np.asarray(size, dtype=np.float64)
    areas = np.array([size[1] * size[2], size[1] * size[2], size[0] * size[2], size[0] * size[2],
                      size[0] * size[1], size[0] * size[1]])
    counts = np.maximum(1, np.round(n * areas / areas.sum())).astype(int)
    spacing = np.sqrt(areas.sum() / max(n, 1))
    pts, nrm, col = [], [], []
    for face, count in enumerate(counts):
        axis, sign = face // 2, 1.0 if face % 2 == 0 else -1.0
        p = rng.uniform(-0.5, 0.5, size=(count, 3)) * size
        p[:, axis] = sign * size[axis] / 2
        normal = np.zeros(3)
        normal[axis] = sign
        pts.append(p)
        nrm.append(np.tile(normal, (count, 1)))
        col.append(np.tile(np.asarray(colors_per_face[face], float), (count, 1)))
    return surface_splats(np.concatenate(pts), np.concatenate(nrm), np.concatenate(col), spacing, rng, **kwargs)


def random_texture(rng: np.random.Generator, period: tuple[float, float], colours: np.ndarray | None = None):
    """A texture function points [N, 3] (m) -> rgb [N, 3] in 0..1: stripes, checks or blobs in ``colours``
    [C, 3] (default: 2-3 random ones; one colour paints it plain), with a feature size drawn from ``period`` (m)."""
    if colours is None:
        colours = rng.uniform(0.05, 0.95, (int(rng.integers(2, 4)), 3))
    period = rng.uniform(*period)
    kind = int(rng.integers(3))
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    phases = rng.uniform(0, 2 * np.pi, 3)

    def texture(points: np.ndarray) -> np.ndarray:
        if kind == 0:  # stripes
            index = np.floor(points @ direction / period)
        elif kind == 1:  # checks
            index = np.floor(points / period).sum(axis=1)
        else:  # blobs
            field = np.sin(points / period + phases).sum(axis=1)
            index = np.floor((field + 3) / 6 * len(colours) * 1.999)
        return colours[index.astype(np.int64) % len(colours)]

    return texture


def striped_label(colors) -> callable:
    """A cup label: horizontal colour bands plus a lettering-like pattern of dark ticks around the cup."""
    colors = np.asarray(colors, dtype=np.float64)

    def texture(angle: np.ndarray, z: np.ndarray) -> np.ndarray:
        band = np.clip(((z - z.min()) / max(np.ptp(z), 1e-9) * len(colors)).astype(int), 0, len(colors) - 1)
        rgb = colors[band].copy()
        ticks = (np.sin(angle * 24) > 0.6) & (np.abs(z - np.median(z)) < 0.01)
        rgb[ticks] = 0.05
        return rgb

    return texture


def tabletop_scene(n_splats: int, rng: np.random.Generator, sh_degree: int = 3):
    """A wooden table (label 0) with 6 objects (labels 1..6) on it; ~70% of the splats in the table.

    Returns (environment, [object clouds in their object frames], [T_world_obj 4x4 poses]).
    """
    n_env = int(0.7 * n_splats)
    env = plane(1.6, 1.2, n_env, wood_texture, rng, sh_degree=sh_degree)
    n_obj = (n_splats - len(env)) // 6
    specs = [
        ("cup", (0.045, 0.11), [(0.9, 0.15, 0.1), (1.0, 0.95, 0.9), (0.9, 0.15, 0.1)]),
        ("cup", (0.05, 0.08), [(1.0, 0.8, 0.1), (0.2, 0.2, 0.8), (1.0, 0.8, 0.1)]),
        ("cup", (0.06, 0.07), [(0.1, 0.6, 0.2), (1.0, 1.0, 1.0), (0.1, 0.6, 0.2)]),
        ("box", (0.12, 0.08, 0.05), [(0.8, 0.3, 0.6)] * 2 + [(0.9, 0.6, 0.7)] * 2 + [(1.0, 0.9, 0.95)] * 2),
        ("cup", (0.035, 0.12), [(0.6, 0.6, 0.65), (0.3, 0.3, 0.35), (0.6, 0.6, 0.65)]),
        ("box", (0.07, 0.07, 0.14), [(0.2, 0.5, 0.9)] * 4 + [(0.9, 0.9, 0.9)] * 2),
    ]
    objects, poses = [], []
    for i, (kind, dims, colors) in enumerate(specs):
        label = i + 1
        if kind == "cup":
            radius, height = dims
            obj = cylinder(radius, height, n_obj, striped_label(colors), colors[0], rng, sh_degree=sh_degree,
                           label=label)
            half_h = height / 2
        else:
            obj = box(dims, n_obj, colors, rng, sh_degree=sh_degree, label=label)
            half_h = dims[2] / 2
        angle = 2 * np.pi * i / len(specs) + rng.uniform(-0.2, 0.2)
        yaw = rng.uniform(0, 2 * np.pi)
        T = np.eye(4)
        T[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
        T[:3, 3] = [0.28 * np.cos(angle), 0.22 * np.sin(angle), half_h]
        objects.append(obj)
        poses.append(T)
    return env, objects, poses

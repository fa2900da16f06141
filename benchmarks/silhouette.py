"""How much larger a mesh's splats render than the mesh itself: the linear size ratio of the rendered silhouette
(alpha >= 0.5) to the mesh's, at three object sizes in pixels, classic and antialiased.

Usage: python benchmarks/silhouette.py MESH [--scale 0.001] [--spacing 0.002] [--views 6]

The mesh is covered with splats as ``pegasus assets import-mesh`` covers an object (``mesh_to_splats``, inset)
and seen from ``--views`` random directions 0.6 m away by a 640x480 camera (fx 572 px) scaled x0.5, x1 and x2.
The mesh's own silhouette is each pixel's covered share (its triangles filled at 8x the resolution and averaged),
taken where it is at least half, so that no pixel convention biases the reference. The ratio is sqrt(splat pixels
/ mesh pixels): the factor by which an object rendered from splats looks larger than it is, which a network trained on
the renders reads as that much nearer.
"""

from __future__ import annotations

import argparse

import numpy as np

from pegasus_gen.geometry.cameras import look_at
from pegasus_gen.render.renderer import render
from pegasus_gen.render.silhouette import mesh_coverage
from pegasus_gen.splats.from_mesh import DEFAULT_SPACING, SILHOUETTE_INSET, load_mesh, mesh_to_splats

SUPERSAMPLE = 8


def camera(scale: float) -> tuple[np.ndarray, int, int]:
    """(K [3, 3], width, height) of the 640x480 camera (fx 572 px) scaled by ``scale`` (pixel centres kept)."""
    K = np.array([[572.0 * scale, 0, 320 * scale + (scale - 1) / 2], [0, 572.0 * scale, 240 * scale + (scale - 1) / 2],
                  [0, 0, 1.0]])
    return K, round(640 * scale), round(480 * scale)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh")
    parser.add_argument("--scale", type=float, default=1.0, help="mesh units to metres (BOP models: 0.001)")
    parser.add_argument("--spacing", type=float, default=DEFAULT_SPACING, help="metres between splats")
    parser.add_argument("--views", type=int, default=6)
    args = parser.parse_args()
    mesh = load_mesh(args.mesh)
    mesh.apply_scale(args.scale)
    splats = mesh_to_splats(mesh, np.random.default_rng(1), spacing=args.spacing, inset=SILHOUETTE_INSET)
    rng, centre = np.random.default_rng(0), mesh.bounds.mean(axis=0)
    views = []
    for _ in range(args.views):
        azimuth, elevation = rng.uniform(0, 2 * np.pi), rng.uniform(0.2, 1.2)
        views.append(look_at(centre + 0.6 * np.array([np.cos(azimuth) * np.cos(elevation),
                                                       np.sin(azimuth) * np.cos(elevation), np.sin(elevation)]),
                             centre))
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    print(f"{args.mesh}: {len(splats)} splats {args.spacing * 1000:g} mm apart, {args.views} views")
    print(f"{'camera':>7} {'object px':>10} {'classic':>8} {'antialiased':>12}")
    for scale in (0.5, 1.0, 2.0):
        K, w, h = camera(scale)
        sizes, ratios = [], {False: [], True: []}
        for T in views:
            mesh_px = (mesh_coverage(vertices, faces, K, T, w, h, SUPERSAMPLE) >= 0.5).sum()
            sizes.append(np.sqrt(mesh_px))
            for antialiased in (False, True):
                alpha = render(splats, K, T, w, h, device="cpu", antialiased=antialiased).alpha
                ratios[antialiased].append(np.sqrt((alpha >= 0.5).sum() / mesh_px))
        print(f"  x{scale:<4g} {np.median(sizes):>10.0f} {np.median(ratios[False]):>8.4f} "
              f"{np.median(ratios[True]):>12.4f}")


if __name__ == "__main__":
    main()

"""Asset pipeline timings: demo library build, splats -> collision mesh, mesh -> splats.

Usage: python benchmarks/assets.py
"""

from __future__ import annotations

import tempfile
import time

import numpy as np
import trimesh

from pegasus_gen.assets.collision import splats_to_mesh
from pegasus_gen.assets.demo_library import build_demo_library
from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.splats.from_mesh import mesh_to_splats


def timed(fn):
    t0 = time.perf_counter()
    result = fn()
    return result, time.perf_counter() - t0


def main():
    with tempfile.TemporaryDirectory() as tmp:
        lib = AssetLibrary(tmp)
        names, cold = timed(lambda: build_demo_library(lib))
        _, warm = timed(lambda: build_demo_library(lib))
        print(f"demo library ({len(names)} assets): build {cold:.1f} s, cached re-check {warm:.1f} s")
    shapes = {"cup": trimesh.creation.cylinder(0.04, 0.1, sections=64),
              "box": trimesh.creation.box((0.12, 0.08, 0.05)),
              "bowl": trimesh.creation.revolve(np.array([[0.0, 0.0], [0.05, 0.0], [0.07, 0.05], [0.06, 0.05],
                                                        [0.042, 0.012], [0.0, 0.012]]), sections=64)}
    print(f"{'shape':>6} {'splats':>8} {'mesh->splats ms':>16} {'splats->mesh s':>15} {'volume err':>11}")
    for name, mesh in shapes.items():
        cloud, t_splat = timed(lambda: mesh_to_splats(mesh, np.random.default_rng(0), spacing=0.002))
        (out, _), t_mesh = timed(lambda: splats_to_mesh(cloud))
        print(f"{name:>6} {len(cloud):>8,} {1000 * t_splat:>16.1f} {t_mesh:>15.2f} "
              f"{100 * (out.volume / mesh.volume - 1):>10.1f}%")


if __name__ == "__main__":
    main()

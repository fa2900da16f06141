"""Frames/s of the splat renderer on a synthetic table-top scene (640x480, SH degree 3).

Usage: python benchmarks/render.py [--sizes 100000 300000 1000000] [--frames 10] [--backends cpu cuda]
Each frame uses a different camera on an orbit around the table; the first frame (JIT / warm-up) is not timed.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from pegasus_gen.geometry.cameras import intrinsics_from_fov, look_at
from pegasus_gen.render.renderer import cuda_status, render
from pegasus_gen.splats import procedural as synthetic


def orbit_cameras(n: int):
    for i in range(n):
        a = 2 * np.pi * i / n
        yield look_at([0.8 * np.cos(a), 0.8 * np.sin(a), 0.55], [0.0, 0.0, 0.05])


def bench(n_splats: int, backend: str, frames: int, width=640, height=480) -> dict:
    rng = np.random.default_rng(0)
    env, objects, poses = synthetic.tabletop_scene(n_splats, rng, sh_degree=3)
    scene = [env] + [o.transformed(T) for o, T in zip(objects, poses)]
    K = intrinsics_from_fov(width, height, 60.0)
    cams = list(orbit_cameras(frames))
    render(scene, K, cams[0], width, height, labels=range(7), device=backend)  # warm-up / compile
    times = []
    for T in cams:
        t0 = time.perf_counter()
        render(scene, K, T, width, height, labels=range(7), device=backend)
        times.append(time.perf_counter() - t0)
    ms = 1000 * float(np.median(times))
    return {"splats": sum(len(p) for p in scene), "backend": backend, "ms": ms, "fps": 1000.0 / ms}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100_000, 300_000, 1_000_000])
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--backends", nargs="+", default=None, help="default: cpu, plus cuda when usable")
    args = parser.parse_args()
    backends = args.backends or (["cpu", "cuda"] if cuda_status()[0] else ["cpu"])
    if "cuda" not in backends:
        print(f"cuda backend not benchmarked: {cuda_status()[1]}")
    print(f"machine: {platform.processor() or platform.machine()}, {__import__('os').cpu_count()} logical cores")
    if "cuda" in backends:
        print(f"gpu: {cuda_status()[1]}")
    print(f"{'splats':>10} {'backend':>8} {'ms/frame':>10} {'frames/s':>10}")
    for n in args.sizes:
        for backend in backends:
            r = bench(n, backend, args.frames)
            print(f"{r['splats']:>10,} {r['backend']:>8} {r['ms']:>10.1f} {r['fps']:>10.1f}", flush=True)


if __name__ == "__main__":
    main()

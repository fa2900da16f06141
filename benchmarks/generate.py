"""End-to-end generation speed: frames/s with rgb, depth and masks written (640x480, 3-6 objects,
the demo wooden table in its room, static scenes). Usage: python benchmarks/generate.py [--scenes 4]
[--frames 10] [--device cpu|cuda|auto] [--workers 1]"""

from __future__ import annotations

import argparse
import tempfile
import time

from pegasus_gen.assets.demo import build_demo_library
from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.dataset.config import load_config
from pegasus_gen.dataset.generate import generate


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=4)
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--device", default="auto")
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        lib = AssetLibrary(f"{tmp}/lib")
        build_demo_library(lib)
        cfg = load_config(None, [f"output={tmp}/ds", f"library={lib.root}", f"scenes={args.scenes}",
                                 f"frames_per_scene={args.frames}", f"device={args.device}",
                                 f"workers={args.workers}",
                                 "environments=[wooden_table]", "min_objects=3",
                                 "objects=[{asset: 1, count: [0, 1]}, {asset: 2, count: [0, 1]},"
                                 " {asset: 5, count: [0, 1]}, {asset: 7, count: [1, 1]}, {asset: 8, count: [1, 2]}]"])
        generate(load_config(None, [f"output={tmp}/warm", f"library={lib.root}", "scenes=1", "frames_per_scene=1",
                                    f"device={args.device}"]))  # JIT / kernels warm
        t0 = time.perf_counter()
        generate(cfg)
        seconds = time.perf_counter() - t0
        splats = len(lib.get("wooden_table").splats)
    frames = args.scenes * args.frames
    print(f"generate: {frames} frames (640x480, rgb+depth+masks, 3-6 objects, {splats / 1000:.0f}k-splat table, "
          f"{args.workers} worker(s), {args.device}) in {seconds:.1f} s = {frames / seconds:.2f} frames/s")


if __name__ == "__main__":
    main()

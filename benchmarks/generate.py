"""End-to-end generation speed: frames/s with rgb, depth and masks written (640x480, 3-6 objects, the demo
wooden table in its room, static scenes), in one process, in ``--workers`` processes and as Ray tasks on a
private local Ray instance with as many CPUs (its start-up included), all with generate's defaults (contact
shadows, appearance randomisation, 1-3 distractors), and in one process with the plain render (all three off).

Usage: python benchmarks/generate.py [--scenes 4] [--frames 10] [--device cpu|cuda|auto] [--workers 2]
       [--runs one,workers,ray,plain]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time

from pegasus_gen.assets.demo_library import build_demo_library
from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.dataset.config import load_config
from pegasus_gen.dataset.generate import generate

OBJECTS = ("[{asset: 1, count: [0, 1]}, {asset: 2, count: [0, 1]}, {asset: 5, count: [0, 1]},"
           " {asset: 7, count: [1, 1]}, {asset: 8, count: [1, 2]}]")
PLAIN = ["shadows.enabled=false", "appearance.enabled=false", "distractors.count=[0, 0]"]
RUNS = {"one": ["workers=1"], "workers": [], "ray": ["ray=local"], "plain": ["workers=1", *PLAIN]}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=4)
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--device", default="auto")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--runs", default="one,workers,ray,plain")
    args = parser.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs")
    with tempfile.TemporaryDirectory() as tmp:
        lib = AssetLibrary(f"{tmp}/lib")
        build_demo_library(lib)
        splats = len(lib.get("wooden_table").splats)
        generate(load_config(None, [f"output={tmp}/warm", f"library={lib.root}", "scenes=1", "frames_per_scene=1",
                                    f"device={args.device}"]))  # JIT / kernels warm
        for run in args.runs.split(","):
            cfg = load_config(None, [f"output={tmp}/{run}", f"library={lib.root}", f"scenes={args.scenes}",
                                     f"frames_per_scene={args.frames}", f"device={args.device}",
                                     f"workers={args.workers}", "environments=[wooden_table]", "min_objects=3",
                                     f"objects={OBJECTS}", *RUNS[run]])
            t0 = time.perf_counter()
            generate(cfg)
            seconds = time.perf_counter() - t0
            frames = args.scenes * args.frames
            how = f"Ray ({cfg.workers} CPUs)" if cfg.ray else f"{cfg.workers} process(es)"
            print(f"generate [{run}]: {frames} frames (640x480, rgb+depth+masks, 3-6 objects, "
                  f"{splats / 1000:.0f}k-splat table, {how}, {args.device}) in {seconds:.1f} s "
                  f"= {frames / seconds:.2f} frames/s")


if __name__ == "__main__":
    main()

"""Where a generated frame's time goes: ``pegasus generate`` with the defaults (640x480, 3-6 demo objects on the
demo wooden table, contact shadows, appearance randomisation, distractors) in one process, each stage of
``dataset.generate`` timed (wall clock, summed over the run) and shown per frame beside the frame's total.

Usage: python benchmarks/generate_profile.py [--scenes 3] [--frames 10] [--objects demo|DIR/models] [--count 1]
    [--device cpu]

``--objects DIR`` takes the objects from a BOP ``models`` folder instead (``obj_*.ply`` in mm, imported once; up to
eight models, ``--count`` instances of each in every scene): the frame cost of large scanned meshes. Stages that
run on the writer threads (image encoding and writing) overlap the next frame's render; they are listed apart.
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path

import pegasus_gen.dataset.generate as gen
import pegasus_gen.dataset.scene as scene
from pegasus_gen.assets.demo_library import build_demo_library
from pegasus_gen.assets.importers import import_mesh
from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.dataset.config import load_config
from pegasus_gen.formats import bop

DEMO_OBJECTS = ("[{asset: 1, count: [0, 1]}, {asset: 2, count: [0, 1]}, {asset: 5, count: [0, 1]},"
                " {asset: 7, count: [1, 1]}, {asset: 8, count: [1, 2]}]")
# (label, module, attribute): the stages of one scene, in order, where the run and the scene look them up
STAGES = (("assets' models + models_eval (once)", gen, "write_models"),
          ("physics drop (per scene)", scene, "drop_objects"),
          ("camera trajectory (per scene)", scene, "camera_trajectory"),
          ("appearance + contact shadows", scene, "place_objects"),
          ("render", scene, "render"),
          ("camera effects", scene, "camera_image"),
          ("label ray casts", scene, "object_depth_window"),
          ("masks + gt_info", bop, "gt_info_entry"),
          ("COCO (per scene)", scene, "scene_coco"))
THREADED = "image encoding + writing (writer threads)"


class Timer:
    """Sums the wall-clock time of wrapped callables by label (thread-safe)."""

    def __init__(self):
        self.seconds, self.lock = defaultdict(float), threading.Lock()

    def wrap(self, label: str, fn):
        @functools.wraps(fn)
        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                with self.lock:
                    self.seconds[label] += time.perf_counter() - t0
        return timed


def install(timer: Timer) -> None:
    """Wrap the stages where the run and the scene look them up."""
    for label, module, name in STAGES:
        setattr(module, name, timer.wrap(label, getattr(module, name)))
    scene.write_image = timer.wrap(THREADED, scene.write_image)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=3)
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--objects", default="demo", help="demo, or a BOP models folder (obj_*.ply, mm)")
    parser.add_argument("--count", type=int, default=1, help="instances of each model of --objects DIR per scene")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs")
    with tempfile.TemporaryDirectory() as tmp:
        lib = AssetLibrary(f"{tmp}/lib")
        build_demo_library(lib)
        objects, what = DEMO_OBJECTS, "3-6 demo objects"
        if args.objects != "demo":
            plys = sorted(Path(args.objects).glob("obj_*.ply"))[:8]
            taken = max(m.obj_id or 0 for m in lib.manifests())  # the demo objects' ids come first
            for ply in plys:
                import_mesh(ply, f"m{ply.stem[4:]}", "object", lib, obj_id=taken + int(ply.stem[4:]), scale=0.001)
            objects = "[" + ", ".join(f"{{asset: m{p.stem[4:]}, count: [{args.count}, {args.count}]}}"
                                      for p in plys) + "]"
            what = f"{args.count} x {len(plys)} objects of {args.objects}"
        common = [f"library={lib.root}", "workers=1", f"device={args.device}", "environments=[wooden_table]",
                  "min_objects=3", f"objects={objects}"]
        gen.generate(load_config(None, [f"output={tmp}/warm", *common, "scenes=1", "frames_per_scene=1"]))
        timer = Timer()
        install(timer)
        t0 = time.perf_counter()
        gen.generate(load_config(None, [f"output={tmp}/run", *common, f"scenes={args.scenes}",
                                        f"frames_per_scene={args.frames}"]))
        total = time.perf_counter() - t0
    frames = args.scenes * args.frames
    print(f"generate: {frames} frames (640x480, {what}, wooden_table, defaults, 1 process, {args.device}) in "
          f"{total:.1f} s = {frames / total:.2f} frames/s, {1000 * total / frames:.0f} ms per frame")
    def row(label: str, seconds: float, share: bool = True) -> None:
        tail = f"{100 * seconds / total:5.1f} %" if share else "(overlapped)"
        print(f"  {label:42s} {1000 * seconds / frames:7.1f} ms/frame {tail}")

    for label, _, _ in STAGES:
        row(label, timer.seconds[label])
    row("rest (loop, JSON, waiting for writers)", total - sum(timer.seconds[label] for label, _, _ in STAGES))
    row(THREADED, timer.seconds[THREADED], share=False)

if __name__ == "__main__":
    main()

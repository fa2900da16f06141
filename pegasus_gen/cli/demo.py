"""`pegasus demo` (the demo objects rendered on the demo table) and `pegasus demo-loop` (the whole loop)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from pegasus_gen.cli import options


def cmd_demo(args) -> int:
    """Built-in demo: the demo objects standing on the demo wooden table, rendered with colour, depth and labels."""
    from pegasus_gen.assets.demo_library import build_demo_library
    from pegasus_gen.assets.library import AssetLibrary
    from pegasus_gen.geometry.cameras import intrinsics_from_fov, look_at
    from pegasus_gen.render.renderer import render
    from pegasus_gen.splats.cloud import concatenate
    from pegasus_gen.splats.ply import write_ply

    out_dir = Path(args.out)
    lib = AssetLibrary(args.library)
    build_demo_library(lib, seed=args.seed)
    scene = [lib.get("wooden_table").splats]
    objects = sorted((m for m in lib.manifests() if m.kind == "object"), key=lambda m: m.obj_id)
    for i, m in enumerate(objects):  # a ring of upright objects, each turned to show its label
        asset = lib.get(m.name)
        angle = 2 * np.pi * i / len(objects)
        T = np.eye(4)
        T[:2, :2] = [[np.cos(angle + 1.2), -np.sin(angle + 1.2)], [np.sin(angle + 1.2), np.cos(angle + 1.2)]]
        T[:3, 3] = [0.24 * np.cos(angle), 0.14 * np.sin(angle), -asset.mesh.bounds[0, 2]]
        scene.append(asset.splats.transformed(T).with_label(m.obj_id))
    K = intrinsics_from_fov(640, 480, 55.0)
    T_cam = look_at([0.05, -0.62, 0.42], [0.0, 0.0, 0.04])
    t0 = time.perf_counter()
    out = render(scene, K, T_cam, 640, 480, background=(0.92, 0.93, 0.96),
                 labels=[m.obj_id for m in objects], device=args.device)
    ms = 1000 * (time.perf_counter() - t0)
    written = options.write_render_outputs(out_dir, out)
    written.append(write_ply(out_dir / "scene.ply", concatenate(scene), include_labels=True))
    print(f"demo: {len(objects)} demo objects on the demo wooden table, {sum(map(len, scene)):,} splats, "
          f"rendered at 640x480 on {out.backend} in {ms:.0f} ms (first call includes JIT compilation)")
    for path in written:
        print(f"  {path}")
    print(f"look at: {out_dir / 'overview.png'}")
    return 0


def cmd_demo_loop(args) -> int:
    from nodes.demo_loop import DemoSettings, run_demo

    t0 = time.perf_counter()
    settings = DemoSettings.full() if args.full else DemoSettings.small()
    report = run_demo(args.out, settings, library=args.library, host=args.host)
    print(f"demo loop done in {(time.perf_counter() - t0) / 60:.1f} min; report: {report}")
    return 0


def add_commands(sub) -> None:
    p = sub.add_parser("demo", help="render the demo objects on the demo table (builds the demo library once)")
    p.add_argument("--out", default="out/demo", help="output folder")
    options.add_library(p)
    options.add_seed(p)
    options.add_device(p)
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("demo-loop", help="generate -> train -> deploy -> grasp on the demo assets, with an HTML report")
    p.add_argument("--out", default="out/demo-loop", help="output folder (must be empty)")
    p.add_argument("--full", action="store_true", help="the GPU-scale settings (5,000 frames, full DOPE, 20 grasps)")
    options.add_library(p)
    options.add_host(p)
    p.set_defaults(func=cmd_demo_loop)

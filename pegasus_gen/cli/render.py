"""`pegasus render` and `pegasus info`: splat PLY files to images, and their summary."""

from __future__ import annotations

import time

import numpy as np

from pegasus_gen.cli import options
from pegasus_gen.errors import PegasusError


def cmd_render(args) -> int:
    options.check_camera(args)
    if not all(0.0 <= v <= 1.0 for v in args.background):
        raise PegasusError(f"--background must be 3 numbers in [0, 1], got {list(args.background)}")
    out_dir = options.output_folder(args.out)
    from pegasus_gen.render.renderer import render
    from pegasus_gen.splats.ply import read_ply

    parts = [read_ply(p).with_label(i) for i, p in enumerate(args.ply)]
    points = np.concatenate([p.means for p in parts])
    if len(points) == 0:
        raise PegasusError(f"{args.ply[0]}: the splat file(s) hold no splats")
    K, T = options.camera(args, points)
    t0 = time.perf_counter()
    out = render(parts, K, T, args.width, args.height, background=args.background, device=args.device)
    ms = 1000 * (time.perf_counter() - t0)
    written = options.write_render_outputs(out_dir, out)
    print(f"rendered {len(points):,} splats at {args.width}x{args.height} on {out.backend} in {ms:.0f} ms "
          f"(labels: file order from 0)")
    for path in written:
        print(f"  {path}")
    return 0


def cmd_info(args) -> int:
    from pegasus_gen.splats.ply import read_ply

    for path in args.ply:
        cloud = read_ply(path)
        print(f"{path}: {len(cloud):,} splats, SH degree {cloud.sh_degree}")
        if len(cloud):
            lo, hi = cloud.means.min(0), cloud.means.max(0)
            print(f"  bounds min {np.round(lo, 4).tolist()} max {np.round(hi, 4).tolist()} (file units)")
            print(f"  opacity median {np.median(cloud.opacities):.3f}, "
                  f"scale median {np.median(cloud.scales):.4g}, labels {np.unique(cloud.labels).tolist()}")
    return 0


def add_commands(sub) -> None:
    p = sub.add_parser("render", help="render 3DGS PLY files (each gets a label by its order) to PNGs")
    p.add_argument("ply", nargs="+", help="3DGS PLY file(s), composed in one scene")
    p.add_argument("--out", default="out/render", help="output folder")
    p.add_argument("--background", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("R", "G", "B"))
    options.add_device(p)
    options.add_camera(p)
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("info", help="summarise 3DGS PLY files")
    p.add_argument("ply", nargs="+")
    p.set_defaults(func=cmd_info)

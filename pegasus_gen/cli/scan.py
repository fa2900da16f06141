"""`pegasus scan` and `pegasus scan-capture`: photos to a splat asset, and a synthetic capture to try it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pegasus_gen.cli import options


def cmd_scan(args) -> int:
    from pegasus_gen.scan.options import ScanOptions

    scan_options = options.config_from_args(ScanOptions, args)  # checked before the pipeline's heavy imports
    from pegasus_gen.scan.pipeline import run_scan

    report = run_scan(args.images, args.work or Path("out/scan") / args.name, scan_options, options.library(args))
    sfm, scale, training = report.sfm, report.scale, report.training
    print(f"registered {sfm['registered']}/{sfm['images']} photos, scale {scale['scale_m_per_unit']:.5g} m/unit, "
          f"held-out PSNR {training.get('psnr_test', float('nan')):.2f} dB, {training['n_splats_final']:,} splats, "
          f"{report.timings_s.total:.0f} s")
    return 0


def cmd_capture(args) -> int:
    from pegasus_gen.io.files import read_json
    from pegasus_gen.scan.capture import write_capture

    images = write_capture(args.out, views=args.views, width=args.size[0], height=args.size[1], seed=args.seed,
                           flipped=args.flipped, markers=not args.no_markers)
    K = np.array(read_json(Path(args.out) / "truth.json")["K"])
    print(f"wrote {args.views} photos to {images} (masks in {Path(args.out) / 'masks'}, truth in truth.json); scan "
          f"them with:\n  pegasus scan {images} --kind object --obj-id 20 --name scanned_cup --aruco-size 0.05 "
          f"--masks {Path(args.out) / 'masks'} --intrinsics {K[0, 0]:.3f} {K[1, 1]:.3f} {K[0, 2]:.1f} {K[1, 2]:.1f}")
    return 0


def add_commands(sub) -> None:
    from pegasus_gen.scan.options import ScanOptions

    p = sub.add_parser("scan", help="photos -> metric, z-up splat asset (SfM, ArUco scale, plane alignment, 3DGS)")
    p.add_argument("images", help="folder of photos")
    options.add_config_flags(p, ScanOptions, (
        "kind", "name", "obj_id", "aruco_size", "aruco_dict", "scale", "intrinsics", "matcher", "masks",
        "second_images", "second_masks", "preset", "iterations", "train_size", "device"),
        kind={"required": True}, name={"required": True}, intrinsics={"metavar": ("FX", "FY", "CX", "CY")})
    p.add_argument("--work", help="work folder for SfM (sfm/), the trained scene, report and previews (default "
                                  "out/scan/NAME); refused when it already holds any of them (a scan deletes "
                                  "nothing it did not make: remove an earlier scan's files, or choose another)")
    options.add_library(p)
    options.add_config_flags(p, ScanOptions, ("seed", "overwrite"))
    p.set_defaults(func=cmd_scan)

    p = sub.add_parser("scan-capture",
                       help="render a synthetic scan capture (cup on an ArUco board) to try pegasus scan")
    p.add_argument("out", help="output folder")
    p.add_argument("--views", type=int, default=36)
    p.add_argument("--size", type=int, nargs=2, default=(480, 360), metavar=("W", "H"))
    p.add_argument("--flipped", action="store_true", help="the cup upside down (second half of a two-part scan)")
    p.add_argument("--no-markers", action="store_true", help="a board without ArUco markers")
    options.add_seed(p)
    p.set_defaults(func=cmd_capture)

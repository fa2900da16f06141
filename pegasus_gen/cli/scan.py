"""`pegasus scan` and `pegasus scan-capture`: photos to a splat asset, and a synthetic capture to try it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pegasus_gen.cli import options


def cmd_scan(args) -> int:
    from pegasus_gen.scan.pipeline import ScanOptions, run_scan

    options = ScanOptions(kind=args.kind, name=args.name, obj_id=args.obj_id, aruco_size=args.aruco_size,
                          aruco_dict=args.aruco_dict, scale=args.scale,
                          intrinsics=tuple(args.intrinsics) if args.intrinsics else None, matcher=args.matcher,
                          masks=args.masks, second_images=args.second_images, second_masks=args.second_masks,
                          preset=args.preset, iterations=args.iterations, train_size=args.train_size, device=args.device,
                          seed=args.seed, overwrite=args.overwrite)
    report = run_scan(args.images, args.work or Path("out/scan") / args.name, options, options.library(args))
    sfm, scale, training = report["sfm"], report["scale"], report["training"]
    print(f"registered {sfm['registered']}/{sfm['images']} photos, scale {scale['scale_m_per_unit']:.5g} m/unit, "
          f"held-out PSNR {training.get('psnr_test', float('nan')):.2f} dB, {training['n_splats_final']:,} splats, "
          f"{report['timings_s']['total']:.0f} s")
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
    p = sub.add_parser("scan", help="photos -> metric, z-up splat asset (SfM, ArUco scale, plane alignment, 3DGS)")
    p.add_argument("images", help="folder of photos")
    p.add_argument("--kind", choices=("object", "environment"), required=True)
    p.add_argument("--name", required=True, help="asset name")
    p.add_argument("--obj-id", type=int, help="BOP object id (objects)")
    p.add_argument("--aruco-size", type=float, help="printed ArUco marker edge length, metres")
    p.add_argument("--aruco-dict", default="DICT_4X4_50", help="cv2.aruco dictionary of the markers")
    p.add_argument("--scale", type=float, help="metres per reconstruction unit, instead of markers")
    p.add_argument("--intrinsics", type=float, nargs=4, metavar=("FX", "FY", "CX", "CY"),
                   help="calibrated pinhole camera (OpenCV pixels); default: estimated by SfM")
    p.add_argument("--matcher", choices=("exhaustive", "sequential"), default="exhaustive",
                   help="exhaustive for up to ~150 photos, sequential for video-like sets")
    p.add_argument("--masks", help="folder of object masks named like the photos (background removal)")
    p.add_argument("--second-images", help="photos of the object turned over (two-part object scan; needs masks)")
    p.add_argument("--second-masks", help="object masks of the second-half photos")
    p.add_argument("--preset", choices=("cpu-small", "7k", "30k"), default="cpu-small",
                   help="splat training length: cpu-small (minutes on a CPU), 7k or 30k iterations (GPU)")
    p.add_argument("--iterations", type=int, help="training steps instead of the preset's (its schedule is kept)")
    p.add_argument("--train-size", type=int,
                   help="longest photo side for splat training, pixels (default 160 for cpu-small, else 1600)")
    options.add_device(p)
    p.add_argument("--work", help="work folder for SfM, report and previews (default out/scan/NAME)")
    options.add_library(p)
    options.add_seed(p)
    p.add_argument("--overwrite", action="store_true", help="replace an existing asset of that name")
    p.set_defaults(func=cmd_scan)

    p = sub.add_parser("scan-capture", help="render a synthetic scan capture (cup on an ArUco board) to try pegasus scan")
    p.add_argument("out", help="output folder")
    p.add_argument("--views", type=int, default=36)
    p.add_argument("--size", type=int, nargs=2, default=(480, 360), metavar=("W", "H"))
    p.add_argument("--flipped", action="store_true", help="the cup upside down (second half of a two-part scan)")
    p.add_argument("--no-markers", action="store_true", help="a board without ArUco markers")
    options.add_seed(p)
    p.set_defaults(func=cmd_capture)

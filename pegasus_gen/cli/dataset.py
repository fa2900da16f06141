"""`pegasus generate`, `validate` and `view`: BOP datasets made, checked and looked at."""

from __future__ import annotations

import time
from pathlib import Path


def cmd_generate(args) -> int:
    from pegasus_gen.dataset.config import load_config
    from pegasus_gen.dataset.generate import generate

    config_file = None
    overrides = list(args.overrides)
    if overrides and "=" not in overrides[0]:
        config_file = overrides.pop(0)
    if args.workers is not None:
        overrides.append(f"workers={args.workers}")
    if args.out is not None:
        overrides.append(f"output={args.out}")
    if args.ray is not None:
        overrides.append(f"ray={args.ray}")
    cfg = load_config(config_file, overrides)
    t0 = time.perf_counter()
    out = generate(cfg, resume=args.resume)
    seconds = time.perf_counter() - t0
    print(f"dataset: {out} ({cfg.scenes} scenes x {cfg.frames_per_scene} frames; this run took {seconds:.1f} s)")
    print(f"check it: pegasus validate {out}    look at it: pegasus view {out}")
    return 0


def cmd_validate(args) -> int:
    from pegasus_gen.dataset.validate import validate

    report = validate(args.dataset, args.split, max_images=args.max_images)
    for problem in report.problems[:50]:
        print(f"  {problem}")
    if len(report.problems) > 50:
        print(f"  ... and {len(report.problems) - 50} more")
    print(report.summary())
    return 0 if report.ok else 1


def cmd_view(args) -> int:
    from pegasus_gen.cli.options import output_folder
    from pegasus_gen.dataset.view import view

    out = output_folder(args.out if args.out is not None else Path(args.dataset) / "view")
    page = view(args.dataset, out, args.split, args.max_images)
    print(f"gallery: {page}")
    return 0


def add_commands(sub) -> None:
    p = sub.add_parser("generate", help="generate a BOP dataset: pegasus generate [CONFIG.yaml] [key=value ...]")
    p.add_argument("overrides", nargs="*", metavar="CONFIG|key=value",
                   help="an optional YAML config first, then overrides such as scenes=10 camera.width=320")
    p.add_argument("--out", help="output folder (same as output=...)")
    p.add_argument("--workers", type=int, help="processes rendering scenes in parallel (same as workers=...)")
    p.add_argument("--ray", metavar="auto|local|ADDRESS",
                   help="run scenes as Ray tasks: on the running cluster (auto), a private local instance with "
                        "--workers CPUs (local) or the cluster at ADDRESS; the output must be on storage every node "
                        "mounts (same as ray=...)")
    p.add_argument("--resume", action="store_true",
                   help="continue the dataset in the output folder (made with the same config)")
    p.set_defaults(func=cmd_generate)

    p = sub.add_parser("validate", help="check a BOP dataset against its models (masks, depth, format)")
    p.add_argument("dataset")
    p.add_argument("--split", default="train_pbr")
    p.add_argument("--max-images", type=int, help="check at most this many images per scene (at least 1)")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("view", help="overlay masks, 3D boxes and axes on a BOP dataset's images; HTML gallery")
    p.add_argument("dataset")
    p.add_argument("--out", help="folder for the overlays and index.html (default: DATASET/view)")
    p.add_argument("--split", default="train_pbr")
    p.add_argument("--max-images", type=int, default=10, help="images per scene")
    p.set_defaults(func=cmd_view)

"""`pegasus assets ...`: the asset library listed, described, imported, and the demo assets built."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pegasus_gen.cli import options


def cmd_list(args) -> int:
    lib = options.library(args)
    manifests = lib.manifests()
    if not manifests:
        print(f"no assets in {lib.root}")
        return 0
    print(f"{len(manifests)} assets in {lib.root}")
    for m in manifests:
        ident = f"obj_id {m.obj_id}" if m.kind == "object" else "environment"
        print(f"  {m.name:<24} {ident}")
    return 0


def cmd_demo(args) -> int:
    from pegasus_gen.assets.demo_library import build_demo_library

    lib = options.library(args)
    names = build_demo_library(lib, seed=args.seed, force=args.force)
    print(f"demo library: {len(names)} assets in {lib.root}: {', '.join(names)}")
    return 0


def cmd_show(args) -> int:
    from pegasus_gen.assets.previews import turntable
    from pegasus_gen.io import images

    asset = options.library(args).get(args.name)
    m = asset.manifest
    print(f"{m.name}: {m.kind}" + (f", obj_id {m.obj_id}, mass {m.mass} kg" if m.kind == "object" else ""))
    print(f"  {len(asset.splats):,} splats (SH degree {asset.splats.sh_degree}), collision mesh "
          f"{len(asset.mesh.faces)} triangles, size {np.round(np.ptp(asset.mesh.bounds, 0), 4).tolist()} m")
    if m.drop_region is not None:
        r = m.drop_region
        print(f"  drop region x [{r.x_min:.3f}, {r.x_max:.3f}] y [{r.y_min:.3f}, {r.y_max:.3f}] m")
    image, ious = turntable(asset, device=args.device)
    path = images.write_image(Path(args.out) / f"{m.name}_turntable.png", image)
    print(f"  splats vs mesh silhouette IoU per view: {' '.join(f'{v:.3f}' for v in ious)}")
    print(f"  preview: {path}")
    return 0


def cmd_import(args) -> int:
    from pegasus_gen.assets import importers

    fields = {"mass": args.mass} if args.mass is not None else {}
    common = dict(name=args.name, kind=args.kind, library=options.library(args), obj_id=args.obj_id, scale=args.scale,
                  transform=args.transform, overwrite=args.overwrite, **fields)
    if args.command_assets == "import-splat":
        asset = importers.import_splat(args.file, **common)
    else:
        asset = importers.import_mesh(args.file, spacing=args.spacing, **common)
    print(f"imported {asset.name} ({asset.manifest.kind}) into {asset.path}: {len(asset.splats):,} splats, "
          f"collision mesh {len(asset.mesh.faces)} triangles")
    return 0


def add_commands(sub) -> None:
    assets = sub.add_parser("assets", help="asset library: list, show, import")
    options.add_library(assets)
    asub = assets.add_subparsers(dest="command_assets", required=True)
    p = asub.add_parser("demo", help="build the built-in demo assets (8 objects, 3 environments) once")
    options.add_seed(p)
    p.add_argument("--force", action="store_true", help="rebuild even if present")
    p.set_defaults(func=cmd_demo)
    p = asub.add_parser("list", help="list the assets")
    p.set_defaults(func=cmd_list)
    p = asub.add_parser("show", help="describe an asset and write a turntable preview PNG")
    p.add_argument("name", help="asset name or obj_id")
    p.add_argument("--out", default="out/assets", help="preview folder")
    options.add_device(p)
    p.set_defaults(func=cmd_show)
    for verb, what in (("import-splat", "a trained 3DGS PLY"),
                       ("import-mesh", "a mesh (OBJ + texture, PLY, STL, GLB)")):
        p = asub.add_parser(verb, help=f"import {what} as an asset")
        p.add_argument("file")
        p.add_argument("--name", required=True)
        p.add_argument("--kind", choices=("object", "environment"), required=True)
        p.add_argument("--obj-id", type=int, help="BOP object id (objects)")
        p.add_argument("--scale", type=float, default=1.0, help="factor from file units to metres")
        p.add_argument("--transform", type=float, nargs=16, metavar="T",
                       help="rigid 4x4 (row-major) applied after scaling, e.g. to make z up")
        p.add_argument("--mass", type=float, help="kg (objects)")
        p.add_argument("--overwrite", action="store_true")
        if verb == "import-mesh":
            p.add_argument("--spacing", type=float, default=0.002, help="splat spacing on the surface, m")
        p.set_defaults(func=cmd_import)

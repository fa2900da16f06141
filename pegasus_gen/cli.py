"""The ``pegasus`` command line: a thin shell over the library functions."""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from pathlib import Path

import numpy as np

from pegasus_gen import __version__
from pegasus_gen.errors import PegasusError


def _camera_from_args(args, points):
    from pegasus_gen.cameras import frame_points, intrinsics, look_at

    K = intrinsics(args.width, args.height, args.fov, args.fx, args.fy, args.cx, args.cy)
    if args.eye is not None:
        target = args.target if args.target is not None else np.median(points, axis=0)
        T = look_at(args.eye, target)
    else:
        T = frame_points(points, K, args.width, args.height, args.azimuth, args.elevation)
    return K, T


def _write_render_outputs(out_dir: Path, out) -> list[Path]:
    from pegasus_gen import images

    depth_mm = np.clip(np.round(out.depth * 1000.0), 0, 65535).astype(np.uint16)
    written = [
        images.write_image(out_dir / "rgb.png", images.rgb_to_uint8(out.rgb)),
        images.write_image(out_dir / "depth_mm.png", depth_mm),
        images.write_image(out_dir / "depth_vis.png", images.colorize_depth(out.depth)),
        images.write_image(out_dir / "labels.png", images.colorize_labels(out.label)),
    ]
    sheet = np.concatenate([images.rgb_to_uint8(out.rgb), images.colorize_depth(out.depth),
                            images.colorize_labels(out.label)], axis=1)
    written.append(images.write_image(out_dir / "overview.png", sheet))
    return written


def cmd_render(args) -> int:
    from pegasus_gen.render import render
    from pegasus_gen.splats import read_ply

    parts = [read_ply(p).with_label(i) for i, p in enumerate(args.ply)]
    points = np.concatenate([p.means for p in parts])
    if len(points) == 0:
        raise PegasusError(f"{args.ply[0]}: the splat file(s) hold no splats")
    K, T = _camera_from_args(args, points)
    t0 = time.perf_counter()
    out = render(parts, K, T, args.width, args.height, background=args.background, device=args.device)
    ms = 1000 * (time.perf_counter() - t0)
    written = _write_render_outputs(Path(args.out), out)
    print(f"rendered {len(points):,} splats at {args.width}x{args.height} on {out.backend} in {ms:.0f} ms "
          f"(labels: file order from 0)")
    for path in written:
        print(f"  {path}")
    return 0


def cmd_info(args) -> int:
    from pegasus_gen.splats import read_ply

    for path in args.ply:
        cloud = read_ply(path)
        print(f"{path}: {len(cloud):,} splats, SH degree {cloud.sh_degree}")
        if len(cloud):
            lo, hi = cloud.means.min(0), cloud.means.max(0)
            print(f"  bounds min {np.round(lo, 4).tolist()} max {np.round(hi, 4).tolist()} (file units)")
            print(f"  opacity median {np.median(cloud.opacities):.3f}, "
                  f"scale median {np.median(cloud.scales):.4g}, labels {np.unique(cloud.labels).tolist()}")
    return 0


def cmd_demo(args) -> int:
    """Built-in demo: the demo objects standing on the demo wooden table, rendered with colour, depth and labels."""
    from pegasus_gen.assets import AssetLibrary
    from pegasus_gen.cameras import intrinsics_from_fov, look_at
    from pegasus_gen.demo_assets import build_demo_library
    from pegasus_gen.render import render
    from pegasus_gen.splats import concatenate, write_ply

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
    written = _write_render_outputs(out_dir, out)
    written.append(write_ply(out_dir / "scene.ply", concatenate(scene), include_labels=True))
    print(f"demo: {len(objects)} demo objects on the demo wooden table, {sum(map(len, scene)):,} splats, "
          f"rendered at 640x480 on {out.backend} in {ms:.0f} ms (first call includes JIT compilation)")
    for path in written:
        print(f"  {path}")
    print(f"look at: {out_dir / 'overview.png'}")
    return 0


def cmd_generate(args) -> int:
    from pegasus_gen.config import load_config
    from pegasus_gen.generate import generate

    config_file = None
    overrides = list(args.overrides)
    if overrides and "=" not in overrides[0]:
        config_file = overrides.pop(0)
    if args.workers is not None:
        overrides.append(f"workers={args.workers}")
    if args.out is not None:
        overrides.append(f"output={args.out}")
    cfg = load_config(config_file, overrides)
    t0 = time.perf_counter()
    out = generate(cfg, resume=args.resume)
    seconds = time.perf_counter() - t0
    print(f"dataset: {out} ({cfg.scenes} scenes x {cfg.frames_per_scene} frames; this run took {seconds:.1f} s)")
    print(f"check it: pegasus validate {out}    look at it: pegasus view {out}")
    return 0


def cmd_validate(args) -> int:
    from pegasus_gen.validate import validate

    report = validate(args.dataset, args.split, max_images=args.max_images)
    for problem in report.problems[:50]:
        print(f"  {problem}")
    if len(report.problems) > 50:
        print(f"  ... and {len(report.problems) - 50} more")
    print(report.summary())
    return 0 if report.ok else 1


def cmd_view(args) -> int:
    from pegasus_gen.view import view

    out = args.out if args.out is not None else Path(args.dataset) / "view"
    page = view(args.dataset, out, args.split, args.max_images)
    print(f"gallery: {page}")
    return 0


def _library(args):
    from pegasus_gen.assets import AssetLibrary

    return AssetLibrary(args.library)


def cmd_assets_list(args) -> int:
    lib = _library(args)
    manifests = lib.manifests()
    if not manifests:
        print(f"no assets in {lib.root}")
        return 0
    print(f"{len(manifests)} assets in {lib.root}")
    for m in manifests:
        ident = f"obj_id {m.obj_id}" if m.kind == "object" else "environment"
        print(f"  {m.name:<24} {ident}")
    return 0


def cmd_assets_demo(args) -> int:
    from pegasus_gen.demo_assets import build_demo_library

    lib = _library(args)
    names = build_demo_library(lib, seed=args.seed, force=args.force)
    print(f"demo library: {len(names)} assets in {lib.root}: {', '.join(names)}")
    return 0


def cmd_assets_show(args) -> int:
    from pegasus_gen import images
    from pegasus_gen.previews import turntable

    asset = _library(args).get(args.name)
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


def cmd_assets_import(args) -> int:
    from pegasus_gen import asset_import

    fields = {"mass": args.mass} if args.mass is not None else {}
    common = dict(name=args.name, kind=args.kind, library=_library(args), obj_id=args.obj_id, scale=args.scale,
                  transform=args.transform, overwrite=args.overwrite, **fields)
    if args.command_assets == "import-splat":
        asset = asset_import.import_splat(args.file, **common)
    else:
        asset = asset_import.import_mesh(args.file, spacing=args.spacing, **common)
    print(f"imported {asset.name} ({asset.manifest.kind}) into {asset.path}: {len(asset.splats):,} splats, "
          f"collision mesh {len(asset.mesh.faces)} triangles")
    return 0


def cmd_scan(args) -> int:
    from pegasus_gen.scan import ScanOptions, run_scan

    options = ScanOptions(kind=args.kind, name=args.name, obj_id=args.obj_id, aruco_size=args.aruco_size,
                          aruco_dict=args.aruco_dict, scale=args.scale,
                          intrinsics=tuple(args.intrinsics) if args.intrinsics else None, matcher=args.matcher,
                          masks=args.masks, second_images=args.second_images, second_masks=args.second_masks,
                          preset=args.preset, iterations=args.iterations, train_size=args.train_size, device=args.device,
                          seed=args.seed, overwrite=args.overwrite)
    report = run_scan(args.images, args.work or Path("out/scan") / args.name, options, _library(args))
    sfm, scale, training = report["sfm"], report["scale"], report["training"]
    print(f"registered {sfm['registered']}/{sfm['images']} photos, scale {scale['scale_m_per_unit']:.5g} m/unit, "
          f"held-out PSNR {training.get('psnr_test', float('nan')):.2f} dB, {training['n_splats_final']:,} splats, "
          f"{report['timings_s']['total']:.0f} s")
    return 0


def cmd_scan_capture(args) -> int:
    from pegasus_gen.files import read_json
    from pegasus_gen.scan_capture import write_capture

    images = write_capture(args.out, views=args.views, width=args.size[0], height=args.size[1], seed=args.seed,
                           flipped=args.flipped, markers=not args.no_markers)
    K = np.array(read_json(Path(args.out) / "truth.json")["K"])
    print(f"wrote {args.views} photos to {images} (masks in {Path(args.out) / 'masks'}, truth in truth.json); scan "
          f"them with:\n  pegasus scan {images} --kind object --obj-id 20 --name scanned_cup --aruco-size 0.05 "
          f"--masks {Path(args.out) / 'masks'} --intrinsics {K[0, 0]:.3f} {K[1, 1]:.3f} {K[0, 2]:.1f} {K[1, 2]:.1f}")
    return 0


def cmd_train(args) -> int:
    from dope_training.train import TrainConfig, train

    cfg = TrainConfig(data=args.data, object=args.object, out=args.out, split=args.split, variant=args.variant,
                      size=args.size, epochs=args.epochs, batch_size=args.batch_size, lr=args.lr,
                      min_visibility=args.min_visibility, augment=not args.no_augment, device=args.device,
                      amp=not args.no_amp, loader_workers=args.loader_workers, seed=args.seed, vgg19=args.vgg19,
                      object_size=args.object_size)
    out = train(cfg, resume=args.resume)
    if int(os.environ.get("RANK", 0)) == 0:  # under torchrun only rank 0 speaks
        print(f"trained: {out}/last.pt    loss curve: {out}/loss.png    export: pegasus export {out}/last.pt")
    return 0


def cmd_export(args) -> int:
    from dope_training.export import export_checkpoint

    out = args.out if args.out is not None else Path(args.checkpoint).with_suffix(".onnx")
    path, diff = export_checkpoint(args.checkpoint, out, opset=args.opset)
    print(f"exported {path} (opset {args.opset}); onnxruntime vs torch max abs diff {diff:.2e}")
    return 0


def _read_K(args, width: int, height: int) -> np.ndarray:
    from pegasus_gen.cameras import intrinsics

    if args.K is not None:
        fx, fy, cx, cy = args.K
        return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dtype=np.float64)
    return intrinsics(width, height, args.fov)


def cmd_infer(args) -> int:
    import json

    import cv2

    from dope_training.infer import DopeModel
    from pegasus_gen import images
    from pegasus_gen.view import draw_instance

    model = DopeModel(args.model, device=args.device)
    image = cv2.imread(str(args.image), cv2.IMREAD_COLOR)
    if image is None:
        raise PegasusError(f"{args.image}: cannot read the image")
    image = image[..., ::-1].copy()
    K = _read_K(args, image.shape[1], image.shape[0])
    t0 = time.perf_counter()
    poses = model.estimate(image, K, min_score=args.min_score)
    ms = 1000 * (time.perf_counter() - t0)
    out = Path(args.out)
    overlay = image.copy()
    obj = model.object
    for n, pose in enumerate(poses):
        draw_instance(overlay, K, pose.T, np.array(obj.bbox_min), np.array(obj.bbox_size), None, None,
                      (255, 60, 200), f"{obj.name} {pose.score:.2f}")
        for x, y in pose.keypoints[np.isfinite(pose.keypoints).all(1)]:
            cv2.circle(overlay, (int(round(x)), int(round(y))), 3, (255, 255, 0), -1, cv2.LINE_AA)
    stem = Path(args.image).stem
    png = images.write_image(out / f"{stem}_poses.png", overlay)
    doc = {"image": str(args.image), "model": str(args.model), "backend": model.backend, "object": obj.name,
           "obj_id": obj.obj_id, "K": K.tolist(), "ms": ms, "instances": [p.to_json() for p in poses]}
    path = out / f"{stem}_poses.json"
    path.write_text(json.dumps(doc, indent=1))
    print(f"{len(poses)} instance(s) of {obj.name!r} in {ms:.0f} ms on {model.backend}")
    for pose in poses:
        print(f"  score {pose.score:.2f}  t = {np.round(pose.T[:3, 3], 4).tolist()} m  "
              f"reprojection {pose.reprojection_error:.1f} px")
    print(f"overlay: {png}\nposes: {path}")
    return 0


def cmd_eval(args) -> int:
    from dope_training.evaluate import evaluate, write_report
    from dope_training.infer import DopeModel

    model = DopeModel(args.model, device=args.device)
    report = evaluate(model, args.data, args.split, min_visibility=args.min_visibility, max_images=args.max_images,
                      min_score=args.min_score)
    out = args.out if args.out is not None else Path(args.model).parent / f"eval_{Path(args.data).name}_{args.split}"
    json_path, png = write_report(report, out)
    r = report["result"]
    print(f"{report['object']['name']}: {report['instances']} instances in {report['images']} images, "
          f"{report['misses']} missed, {report['false_positives']} false positives")
    print(f"{report['metric']}: AUC(0-10 cm) {r['auc_0_10cm']:.3f}, pass 2/5/10 cm "
          f"{r['pass_2cm']:.2f}/{r['pass_5cm']:.2f}/{r['pass_10cm']:.2f}")
    print(f"report: {json_path}    curve: {png}")
    return 0


def cmd_sim_robot(args) -> int:
    from robot_bridge.sim_controller import serve

    return serve(args.host, args.log, args.rate, args.time_scale, args.basket)


def cmd_launch(args) -> int:
    from nodes.launch import run

    nodes = run(args.file, args.arguments)
    print(f"launch: {len(nodes)} node(s) ran: {', '.join(n.get_name() for n in nodes)}")
    return 0


LAUNCH_DIR = Path(__file__).resolve().parents[1] / "launch"


def cmd_sim_grasp(args) -> int:
    import json

    from nodes.launch import run

    overrides = [f"pose_source:={'ground_truth' if args.ground_truth else 'dope'}", f"attempts:={args.attempts}",
                 f"objects:={args.objects}", f"host:={args.host}", f"time_scale:={args.time_scale}",
                 f"report:={args.out}", f"seed:={args.seed}", f"device:={args.device}"]
    if args.model:
        overrides.append(f"model:={args.model}")
    elif not args.ground_truth:
        raise PegasusError("sim-grasp: give --model MODEL.onnx (or --ground-truth to measure grasping alone)")
    if args.library:
        overrides.append(f"library:={args.library}")
    run(LAUNCH_DIR / "sim_pick_place.launch.py", overrides)
    report = json.loads((Path(args.out) / "report.json").read_text())
    print(f"sim-grasp ({report['pose_source']} poses): {report['successes']} of {report['attempts']} in the basket; "
          f"failures: {report['failure_causes'] or 'none'}")
    print(f"report: {Path(args.out) / 'report.json'}    strip: {Path(args.out) / 'strip.png'}")
    return 0


def cmd_demo_loop(args) -> int:
    from nodes.demo import run_demo

    t0 = time.perf_counter()
    report = run_demo(args.out, full=args.full, library=args.library, host=args.host)
    print(f"demo loop done in {(time.perf_counter() - t0) / 60:.1f} min; report: {report}")
    return 0


def _add_camera_args(p):
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--fov", type=float, default=60.0, help="horizontal field of view, degrees (unless --fx)")
    p.add_argument("--fx", type=float, help="focal length in pixels (fy defaults to fx)")
    p.add_argument("--fy", type=float)
    p.add_argument("--cx", type=float, help="principal point (default: image centre)")
    p.add_argument("--cy", type=float)
    p.add_argument("--eye", type=float, nargs=3, metavar=("X", "Y", "Z"), help="camera position (world, m)")
    p.add_argument("--target", type=float, nargs=3, metavar=("X", "Y", "Z"), help="point looked at")
    p.add_argument("--azimuth", type=float, default=-60.0, help="auto-framing azimuth, degrees")
    p.add_argument("--elevation", type=float, default=35.0, help="auto-framing elevation, degrees")


def _check_camera_args(parser, args):
    if args.width <= 0 or args.height <= 0:
        parser.error(f"--width and --height must be positive, got {args.width} x {args.height}")
    if not 1.0 <= args.fov <= 179.0:
        parser.error(f"--fov must be within 1..179 degrees, got {args.fov}")
    for name in ("fx", "fy"):
        value = getattr(args, name)
        if value is not None and value <= 0:
            parser.error(f"--{name} must be positive, got {value}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pegasus", description="Gaussian-splat scans to 6DoF pose datasets.")
    parser.add_argument("--version", action="version", version=f"pegasus {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log more")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("render", help="render 3DGS PLY files (each gets a label by its order) to PNGs")
    p.add_argument("ply", nargs="+", help="3DGS PLY file(s), composed in one scene")
    p.add_argument("--out", default="out/render", help="output folder")
    p.add_argument("--background", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("R", "G", "B"))
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    _add_camera_args(p)
    p.set_defaults(func=cmd_render, check=_check_camera_args)

    p = sub.add_parser("info", help="summarise 3DGS PLY files")
    p.add_argument("ply", nargs="+")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("generate", help="generate a BOP dataset: pegasus generate [CONFIG.yaml] [key=value ...]")
    p.add_argument("overrides", nargs="*", metavar="CONFIG|key=value",
                   help="an optional YAML config first, then overrides such as scenes=10 camera.width=320")
    p.add_argument("--out", help="output folder (same as output=...)")
    p.add_argument("--workers", type=int, help="processes rendering scenes in parallel (same as workers=...)")
    p.add_argument("--resume", action="store_true",
                   help="continue the dataset in the output folder (made with the same config)")
    p.set_defaults(func=cmd_generate)

    p = sub.add_parser("validate", help="check a BOP dataset against its models (masks, depth, format)")
    p.add_argument("dataset")
    p.add_argument("--split", default="train_pbr")
    p.add_argument("--max-images", type=int, help="check at most this many images per scene")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("view", help="overlay masks, 3D boxes and axes on a BOP dataset's images; HTML gallery")
    p.add_argument("dataset")
    p.add_argument("--out", help="folder for the overlays and index.html (default: DATASET/view)")
    p.add_argument("--split", default="train_pbr")
    p.add_argument("--max-images", type=int, default=10, help="images per scene")
    p.set_defaults(func=cmd_view)

    p = sub.add_parser("train", help="train DOPE for one object on BOP datasets (or DOPE/NDDS folders)")
    p.add_argument("--data", action="append", required=True, help="BOP dataset root or DOPE/NDDS folder (repeatable)")
    p.add_argument("--object", required=True, help="obj_id or name (BOP), class name (NDDS)")
    p.add_argument("--out", default="runs/dope", help="output folder (checkpoints, loss curve, belief snapshots)")
    p.add_argument("--split", default="train_pbr")
    p.add_argument("--variant", choices=("full", "light"), default="light",
                   help="full: the original DOPE (GPU); light: 3 narrow stages for CPU")
    p.add_argument("--epochs", type=int, default=10)
    p.add_argument("--batch-size", type=int, default=8, help="per process")
    p.add_argument("--size", type=int, default=0, help="crop size, px (default: full 400, light 320)")
    p.add_argument("--lr", type=float, default=0.0, help="Adam learning rate (default: full 1e-4, light 1e-3)")
    p.add_argument("--min-visibility", type=float, default=0.1, help="skip instances seen less than this")
    p.add_argument("--no-augment", action="store_true", help="nominal-scale crops around the instances only")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument("--no-amp", action="store_true", help="full precision on CUDA")
    p.add_argument("--loader-workers", type=int, default=2, help="data loading processes per training process")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--vgg19", help="ImageNet VGG19 weights (torchvision vgg19-*.pth); default: torch hub cache")
    p.add_argument("--object-size", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="model box size in metres (DOPE/NDDS data)")
    p.add_argument("--resume", action="store_true", help="continue the training in --out (more --epochs)")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("export", help="export a training checkpoint to ONNX and check it against torch")
    p.add_argument("checkpoint")
    p.add_argument("--out", help="ONNX file (default: the checkpoint's path with .onnx)")
    p.add_argument("--opset", type=int, default=17)
    p.set_defaults(func=cmd_export)

    for name, text in (("infer", "estimate object poses in an image; writes an overlay PNG and JSON"),
                       ("eval", "ADD/ADD-S of a model on a BOP split; writes a JSON report and a PNG curve")):
        p = sub.add_parser(name, help=text)
        p.add_argument("--model", required=True, help="ONNX export (onnxruntime) or training checkpoint .pt (torch)")
        p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="cpu")
        p.add_argument("--min-score", type=float, default=0.1, help="lowest centroid belief kept")
    p = sub.choices["infer"]
    p.add_argument("--image", required=True)
    p.add_argument("--K", type=float, nargs=4, metavar=("FX", "FY", "CX", "CY"), help="camera intrinsics, px")
    p.add_argument("--fov", type=float, default=60.0, help="horizontal field of view, degrees, when no --K")
    p.add_argument("--out", default="out/infer")
    p.set_defaults(func=cmd_infer)
    p = sub.choices["eval"]
    p.add_argument("--data", required=True, help="BOP dataset root")
    p.add_argument("--split", default="train_pbr")
    p.add_argument("--min-visibility", type=float, default=0.1)
    p.add_argument("--max-images", type=int, help="per scene")
    p.add_argument("--out", help="report folder (default: beside the model)")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("sim-robot", help="run the simulated UR5 controller that ur-rtde clients drive (Ctrl-C stops)")
    p.add_argument("--host", default="127.0.0.1", help="loopback address to listen on (any 127.x.y.z)")
    p.add_argument("--log", help="write every command that reaches the cell to this file")
    p.add_argument("--rate", type=float, default=125.0, help="control rate, Hz")
    p.add_argument("--time-scale", type=float, default=1.0,
                   help="simulated seconds per second (e.g. 4: motions take a quarter of their time)")
    p.add_argument("--basket", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="put a basket with its floor centre here (base frame, m)")
    p.set_defaults(func=cmd_sim_robot)

    p = sub.add_parser("launch", help="run a ROS 2-style launch file without ROS: pegasus launch FILE [name:=value ...]")
    p.add_argument("file", help="a *.launch.py file")
    p.add_argument("arguments", nargs="*", metavar="name:=value")
    p.set_defaults(func=cmd_launch)

    p = sub.add_parser("sim-grasp", help="closed-loop grasp evaluation in the simulated cell (sim_pick_place.launch.py)")
    p.add_argument("--model", help="DOPE ONNX export")
    p.add_argument("--ground-truth", action="store_true", help="drive the robot with the true poses (grasping alone)")
    p.add_argument("--attempts", type=int, default=20)
    p.add_argument("--objects", default="noodle_cup_red,noodle_cup_curry", help="asset names, comma-separated")
    p.add_argument("--out", default="out/sim_grasp", help="report folder")
    p.add_argument("--host", default="127.0.0.1", help="loopback address for the simulated controller")
    p.add_argument("--time-scale", type=float, default=2.0, help="simulated seconds per second")
    p.add_argument("--library", help="asset library (default: $PEGASUS_ASSETS or ~/.cache/pegasus/assets)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto", help="splat renderer")
    p.set_defaults(func=cmd_sim_grasp)

    p = sub.add_parser("demo-loop", help="generate -> train -> deploy -> grasp on the demo assets, with an HTML report")
    p.add_argument("--out", default="out/demo-loop", help="output folder (must be empty)")
    p.add_argument("--full", action="store_true", help="the GPU-scale settings (5,000 frames, full DOPE, 20 grasps)")
    p.add_argument("--library", help="asset library (default: $PEGASUS_ASSETS or ~/.cache/pegasus/assets)")
    p.add_argument("--host", default="127.0.0.1", help="loopback address for the simulated controller")
    p.set_defaults(func=cmd_demo_loop)

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
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument("--work", help="work folder for SfM, report and previews (default out/scan/NAME)")
    p.add_argument("--library", help="asset library (default: $PEGASUS_ASSETS or ~/.cache/pegasus/assets)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--overwrite", action="store_true", help="replace an existing asset of that name")
    p.set_defaults(func=cmd_scan)

    p = sub.add_parser("scan-capture", help="render a synthetic scan capture (cup on an ArUco board) to try pegasus scan")
    p.add_argument("out", help="output folder")
    p.add_argument("--views", type=int, default=36)
    p.add_argument("--size", type=int, nargs=2, default=(480, 360), metavar=("W", "H"))
    p.add_argument("--flipped", action="store_true", help="the cup upside down (second half of a two-part scan)")
    p.add_argument("--no-markers", action="store_true", help="a board without ArUco markers")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=cmd_scan_capture)

    assets = sub.add_parser("assets", help="asset library: list, show, import")
    assets.add_argument("--library", help="library folder (default: $PEGASUS_ASSETS or ~/.cache/pegasus/assets)")
    asub = assets.add_subparsers(dest="command_assets", required=True)
    p = asub.add_parser("demo", help="build the built-in demo assets (8 objects, 3 environments) once")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--force", action="store_true", help="rebuild even if present")
    p.set_defaults(func=cmd_assets_demo)
    p = asub.add_parser("list", help="list the assets")
    p.set_defaults(func=cmd_assets_list)
    p = asub.add_parser("show", help="describe an asset and write a turntable preview PNG")
    p.add_argument("name", help="asset name or obj_id")
    p.add_argument("--out", default="out/assets", help="preview folder")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.set_defaults(func=cmd_assets_show)
    for verb, what in (("import-splat", "a trained 3DGS PLY"), ("import-mesh", "a mesh (OBJ + texture, PLY, STL, GLB)")):
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
        p.set_defaults(func=cmd_assets_import)

    p = sub.add_parser("demo", help="render the demo objects on the demo table (builds the demo library once)")
    p.add_argument("--out", default="out/demo", help="output folder")
    p.add_argument("--library", help="library folder (default: $PEGASUS_ASSETS or ~/.cache/pegasus/assets)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.set_defaults(func=cmd_demo)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "check", None):
        args.check(parser, args)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(message)s")
    try:
        return args.func(args)
    except PegasusError as exc:
        print(f"pegasus: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pegasus: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

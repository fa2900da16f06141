"""`pegasus train`, `train-zoom`, `export`, `infer` and `eval`: DOPE (and its zoom network) trained, exported to
ONNX, run and scored."""

from __future__ import annotations

import argparse
import os
import time
import warnings
from pathlib import Path

import numpy as np

from pegasus_gen.cli import options
from pegasus_gen.errors import PegasusError


def cmd_train(args) -> int:
    from dope_training.train import TrainConfig, train

    out = train(options.config_from_args(TrainConfig, args), resume=args.resume)
    if int(os.environ.get("RANK", 0)) == 0:  # under torchrun only rank 0 speaks
        print(f"trained: {out}/last.pt    loss curve: {out}/loss.png    export: pegasus export {out}/last.pt")
    return 0


def cmd_train_zoom(args) -> int:
    from dope_training.zoom_config import ZoomConfig
    from dope_training.zoom_train import train_zoom

    cfg = options.config_from_args(ZoomConfig, args)
    _output_file(cfg.out, "--out")
    out = train_zoom(cfg)
    print(f"trained: {out}    use: pegasus eval --model MODEL --zoom {out}")
    return 0


def cmd_export(args) -> int:
    from dope_training.export import export_checkpoint

    out = _output_file(args.out if args.out is not None else Path(args.checkpoint).with_suffix(".onnx"), "--out")
    path, diff = export_checkpoint(args.checkpoint, out, opset=args.opset)
    print(f"exported {path} (opset {args.opset}); onnxruntime vs torch max abs diff {diff:.2e}")
    return 0


def _output_file(path, flag: str) -> Path:
    """The output file named by ``flag``, refused (PegasusError) before any work when it is a folder or a file
    stands where its folder should be."""
    path = Path(path)
    if path.is_dir():
        raise PegasusError(f"{flag} {path} is a folder, not a file")
    options.output_folder(path.parent, flag)
    return path


def _check_camera(args) -> None:
    """A PegasusError unless ``--K`` has fx, fy > 0 and every value finite, and ``--fov`` is in (0, 180) degrees."""
    if args.K is not None:
        fx, fy, cx, cy = args.K
        if not (np.isfinite(args.K).all() and fx > 0 and fy > 0):
            raise PegasusError(f"--K {fx:g} {fy:g} {cx:g} {cy:g}: fx, fy > 0 and cx, cy finite (px) expected")
    elif not 0 < args.fov < 180:
        raise PegasusError(f"--fov {args.fov:g}: a horizontal field of view in (0, 180) degrees expected")


def _read_K(args, width: int, height: int) -> np.ndarray:
    """K [3, 3] px: ``--K FX FY CX CY`` if given, else from ``--fov`` (degrees) and the image size."""
    from pegasus_gen.geometry.cameras import intrinsics

    return intrinsics(width, height, args.fov, *(args.K or ()))


def _read_image(path) -> np.ndarray:
    """The RGB image [H, W, 3] uint8 at ``path``; a PegasusError when it cannot be read or its header gives more
    pixels than PIL's decompression-bomb bound (``Image.MAX_IMAGE_PIXELS``, about 89 MP: 270 MB decoded),
    checked before decoding."""
    from PIL import Image

    from pegasus_gen.io.images import read_rgb

    with warnings.catch_warnings():
        warnings.simplefilter("error", Image.DecompressionBombWarning)
        try:
            Image.open(path).close()  # reads the header only, and checks its size
        except (Image.DecompressionBombWarning, Image.DecompressionBombError):
            raise PegasusError(f"{path}: more than the {Image.MAX_IMAGE_PIXELS / 1e6:.0f} megapixels an image may "
                               "have; not decoded") from None
        except (OSError, ValueError):
            raise PegasusError(f"{path}: cannot read the image") from None
    return read_rgb(path)


def cmd_infer(args) -> int:
    from dope_training.infer import DopeModel
    from dope_training.overlay import write_poses
    from dope_training.refine_rgb import read_mesh
    from pegasus_gen.formats.bop import read_depth_png

    options.output_folder(args.out)
    _check_camera(args)
    model = DopeModel(args.model, device=args.device, use_distance_head=args.distance_head, zoom=args.zoom)
    image = _read_image(args.image)
    K = _read_K(args, image.shape[1], image.shape[0])
    depth = None
    if args.depth is not None:
        depth = read_depth_png(args.depth, args.depth_scale)
        if depth.shape != image.shape[:2]:
            raise PegasusError(f"{args.depth}: a {depth.shape[1]}x{depth.shape[0]} depth image for a "
                               f"{image.shape[1]}x{image.shape[0]} image")
    mesh = None if args.refine_rgb is None else read_mesh(args.refine_rgb, args.mesh_scale)
    t0 = time.perf_counter()
    poses = model.estimate(image, K, min_score=args.min_score, depth_m=depth, mesh=mesh)
    ms = 1000 * (time.perf_counter() - t0)
    obj = model.object
    png, path = write_poses(args.out, args.image, image, K, poses, model, ms)
    print(f"{len(poses)} instance(s) of {obj.name!r} in {ms:.0f} ms on {model.backend}")
    for pose in poses:
        support = "" if pose.support is None else f" (detection {pose.detection_score:.2f} x outline support " \
            f"{pose.support:.2f})"
        print(f"  score {pose.score:.2f}{support}  " + ("PnP: no pose from its keypoints" if pose.T is None else
              f"t = {np.round(pose.T[:3, 3], 4).tolist()} m  reprojection {pose.reprojection_error:.1f} px"))
        r = pose.refinement
        if r is not None:
            print(f"    depth-refined t = {np.round(r.T[:3, 3], 4).tolist()} m  fitness {r.fitness:.2f}  "
                  f"rmse {r.rmse_m * 1000:.1f} mm  " + ("accepted" if r.accepted else f"rejected: {r.reason}"))
        if pose.rgb_refinement is not None:
            g = pose.rgb_refinement
            print(f"    RGB-refined t = {np.round(g.T[:3, 3], 4).tolist()} m  outline support {g.support:.2f}")
    print(f"overlay: {png}\nposes: {path}")
    return 0


def cmd_eval(args) -> int:
    from dope_training.evaluate import describe_found, evaluate, write_eval_report
    from dope_training.infer import DopeModel
    from pegasus_gen.formats.bop import write_bop_results

    out = args.out if args.out is not None else Path(args.model).parent / f"eval_{Path(args.data).name}_{args.split}"
    options.output_folder(out)
    if args.bop_results:
        _output_file(args.bop_results, "--bop-results")
    model = DopeModel(args.model, device=args.device, use_distance_head=args.distance_head, zoom=args.zoom)
    report = evaluate(model, args.data, args.split, min_visibility=args.min_visibility, max_images=args.max_images,
                      min_score=args.min_score, refine=args.depth, refine_rgb=args.refine_rgb)
    json_path, png, gallery = write_eval_report(report, out)
    if args.bop_results:
        path = write_bop_results(args.bop_results, report["estimates"])
        print(f"BOP19 results ({len(report['estimates'])} estimates): {path}")
    r = report["result"]
    print(f"{report['object']['name']}{' (refined against the images)' if args.refine_rgb else ''}: "
          f"{report['instances']} instances in {report['images']} images, "
          f"{report['misses']} missed, {report['false_positives']} false positives "
          f"({report['false_positives_per_image']:.2f} per image)")
    print(f"{report['metric']}: recall at 0.1 d {r['recall_0_1d']:.3f}, AUC(0-10 cm) {r['auc_0_10cm']:.3f}, "
          "pass 2/5/10 cm "
          f"{r['pass_2cm']:.2f}/{r['pass_5cm']:.2f}/{r['pass_10cm']:.2f}")
    print(f"median of the estimates on an instance: {describe_found(report['found_poses'])}")
    if "top_n" in report:  # the split names its targets (how many of each object an image holds): BOP's rule
        top = report["top_n"]
        print(f"{report['metric']} under BOP's top-n rule (the split's targets): recall at 0.1 d "
              f"{top['result']['recall_0_1d']:.3f}, AUC(0-10 cm) {top['result']['auc_0_10cm']:.3f}, "
              f"{top['misses']} of {top['instances']} missed, {top['off_target_per_image']:.2f} off-target per image")
    if "refined" in report:
        r = report["refined"]["result"]
        print(f"{report['metric']} with depth refinement: recall at 0.1 d {r['recall_0_1d']:.3f}, AUC(0-10 cm) "
              f"{r['auc_0_10cm']:.3f}, pass 2/5/10 cm {r['pass_2cm']:.2f}/{r['pass_5cm']:.2f}/{r['pass_10cm']:.2f} "
              f"({report['refined']['rejected']} estimates rejected)")
    print(f"report: {json_path}    curve: {png}" + (f"    worst images: {gallery}" if gallery else ""))
    return 0


def add_commands(sub) -> None:
    from dope_training.train_config import TrainConfig
    from dope_training.zoom_config import ZoomConfig

    p = sub.add_parser("train", help="train DOPE for one object on BOP datasets (or DOPE/NDDS folders)")
    options.add_config_flags(p, TrainConfig, (
        "data", "object", "out", "split", "variant", "frozen_blocks", "batch_norm", "epochs", "batch_size", "size",
        "focal_px", "lr", "schedule", "peak_weight", "keypoints", "surface_points", "symmetry_axis", "min_visibility",
        "negatives", "occluders", "hidden_share", "backgrounds", "background_photos", "blur_px", "blur_linear_light",
        "colour_jitter", "hue_deg", "augment", "device", "amp", "loader_workers", "seed", "vgg19", "object_size",
        "distance_head", "distance_off_axis", "distance_grad"),
        data={"action": "append", "nargs": None, "help": "BOP dataset root or DOPE/NDDS folder (repeatable)"},
        batch_norm={"action": argparse.BooleanOptionalAction},
        object_size={"metavar": ("X", "Y", "Z")}, symmetry_axis={"metavar": ("X", "Y", "Z")})
    p.add_argument("--resume", action="store_true", help="continue the training in --out (more --epochs)")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("train-zoom", help="train the zoomed second look at each estimate (its centre and distance; "
                       "with --rotation its rotation too; with --look outline the object's outline, fitted) "
                       "for one object on BOP datasets")
    options.add_config_flags(p, ZoomConfig, (
        "data", "object", "out", "split", "epochs", "per_instance", "batch_size", "lr", "crop_px", "object_px",
        "centre_std", "distance_std", "rotation_std_deg", "rotation", "view", "look", "min_visibility", "backgrounds",
        "background_photos", "occluders", "blur_px", "colour_jitter", "hue_deg", "device", "seed"),
        data={"action": "append", "nargs": None, "help": "BOP dataset root (repeatable)"})
    p.set_defaults(func=cmd_train_zoom)

    p = sub.add_parser("export", help="export a training checkpoint to ONNX and check it against torch")
    p.add_argument("checkpoint")
    p.add_argument("--out", help="ONNX file (default: the checkpoint's path with .onnx)")
    p.add_argument("--opset", type=int, default=17)
    p.set_defaults(func=cmd_export)

    for name, text in (("infer", "estimate object poses in an image; writes an overlay PNG and JSON"),
                       ("eval", "ADD/ADD-S of a model on a BOP split; writes a JSON report and a PNG curve")):
        p = sub.add_parser(name, help=text)
        p.add_argument("--model", required=True, help="ONNX export (onnxruntime) or training checkpoint .pt (torch)")
        options.add_device(p, default="cpu")
        p.add_argument("--min-score", type=float, default=0.1,
                       help="lowest score kept: the detection score (geometric mean of the centroid's and corners' "
                       "beliefs), with --zoom times the share of the outline the image supports")
        p.add_argument("--no-distance-head", dest="distance_head", action="store_false",
                       help="place the poses where PnP puts them even when the network has a distance head")
        p.add_argument("--zoom", metavar="CHECKPOINT", action="append",
                       help="a zoom network of the same object (pegasus train-zoom): a second, zoomed-in look at each "
                       "estimate moves it; repeatable, applied in the order given (the offsets look, then the "
                       "outline look); each estimate is then scored by its detection score times the share of its "
                       "outline the image's colour edges support")
    p = sub.choices["infer"]
    p.add_argument("--image", required=True)
    p.add_argument("--K", type=float, nargs=4, metavar=("FX", "FY", "CX", "CY"), help="camera intrinsics, px")
    p.add_argument("--fov", type=float, default=60.0, help="horizontal field of view, degrees, when no --K")
    refine = p.add_mutually_exclusive_group()
    refine.add_argument("--depth", help="depth image aligned to --image (16-bit png): refine the poses against it")
    refine.add_argument("--refine-rgb", metavar="MESH", help="the object's mesh (model frame): refine the poses "
                        "against the image, its silhouette fitted to the image's colour edges")
    p.add_argument("--depth-scale", type=float, default=1.0, help="mm per depth unit (BOP PBR datasets: 0.1)")
    p.add_argument("--mesh-scale", type=float, default=1.0, help="metres per mesh unit (BOP models: 0.001)")
    p.add_argument("--out", default="out/infer")
    p.set_defaults(func=cmd_infer)
    p = sub.choices["eval"]
    p.add_argument("--data", required=True, help="BOP dataset root")
    p.add_argument("--split", default="train_pbr")
    p.add_argument("--min-visibility", type=float, default=0.1)
    p.add_argument("--max-images", type=int, help="per scene")
    refine = p.add_mutually_exclusive_group()
    refine.add_argument("--depth", action="store_true", help="also refine every estimate with the frame's depth image")
    refine.add_argument("--refine-rgb", action="store_true", help="refine every estimate against the image (the "
                        "silhouette of the dataset's model of the object fitted to its colour edges) and score it by "
                        "its belief times the share of its outline the image supports; the report is of these poses")
    p.add_argument("--out", help="report folder (default: beside the model)")
    p.add_argument("--bop-results", metavar="CSV", help="also write every estimate as a BOP19 results file "
                   "(bop_toolkit's eval_bop19_pose.py scores it): with --depth the refined poses the refinement "
                   "accepted, with --refine-rgb the RGB-refined poses, else the PnP poses")
    p.set_defaults(func=cmd_eval)

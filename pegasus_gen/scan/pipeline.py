"""The scan pipeline: a folder of photos -> a metric, z-up Gaussian-splat asset in the library.

Steps (``run_scan``): ArUco detection (fails early when metric scale is impossible) -> structure from
motion (:mod:`pegasus_gen.scan.sfm`) -> metric scale from the markers (:mod:`pegasus_gen.scan.markers`) ->
alignment (support plane by RANSAC to z = 0, z up; an object centred over the origin) -> 3DGS training
on the posed photos (:mod:`pegasus_gen.scan.training`) -> crop to the object -> asset (through
:func:`pegasus_gen.assets.importers.import_cloud`: collision mesh, URDF, manifest).

Everything except the asset goes to the work folder: ``sfm/`` (COLMAP database and model),
``splats_aligned.ply`` (the trained scene, metric z-up), ``scan_report.json``, ``training_loss.png`` and
``preview.png`` (held-out photos above their renders). The asset is written last, so a failure leaves no asset.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d

from pegasus_gen.assets.importers import import_cloud, support_plane_alignment
from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.errors import PegasusError
from pegasus_gen.io.images import rgb_to_uint8, write_image
from pegasus_gen.io.plots import line_chart
from pegasus_gen.scan import markers as scan_markers
from pegasus_gen.scan import sfm
from pegasus_gen.splats.cloud import SplatCloud
from pegasus_gen.splats.ply import write_ply

MIN_REGISTERED_FRACTION = 0.5  # below this the photos are too unrelated to trust the reconstruction
OBJECT_MIN_HEIGHT = 0.004  # m: SfM points this far above the support plane are candidates for the object
OBJECT_CLUSTER_EPS = 0.02  # m: DBSCAN neighbourhood joining object points into one cluster
OBJECT_MARGIN = 0.01  # m added around the object's extent when cropping the trained splats
CROP_MIN_HEIGHT = 0.002  # m: trained splats below this height belong to the support plane
TRAIN_SIZE = {"cpu-small": 160, "7k": 1600, "30k": 1600}  # default longest photo side for training, px


@dataclass
class ScanOptions:
    """Everything ``run_scan`` needs besides the photos. Lengths in metres, image sizes in pixels."""

    kind: str = "object"  # "object" or "environment"
    name: str = "scan"
    obj_id: int | None = None
    aruco_size: float | None = None  # printed marker edge length
    aruco_dict: str = "DICT_4X4_50"
    scale: float | None = None  # metres per reconstruction unit, instead of markers
    intrinsics: tuple[float, float, float, float] | None = None  # fx, fy, cx, cy (OpenCV) if calibrated
    matcher: str = "exhaustive"
    masks: str | None = None  # folder of object masks named like the photos (non-zero = object)
    second_images: str | None = None  # the object turned over (second half of an object scan)
    second_masks: str | None = None  # its masks (both halves need masks: only the object moved)
    preset: str = "cpu-small"  # splat training preset
    iterations: int | None = None  # overrides the preset's length (its schedule is kept)
    train_size: int | None = None  # longest image side for splat training (None: by preset)
    holdout_every: int = 8  # every n-th registered photo is held out for PSNR
    device: str = "auto"
    seed: int = 0
    overwrite: bool = False


def _log(message: str) -> None:
    print(message, flush=True)


def _check_options(options: ScanOptions, image_dir: Path, names: list[str], library: AssetLibrary) -> None:
    if options.kind not in ("object", "environment"):
        raise PegasusError(f"--kind must be 'object' or 'environment', got {options.kind!r}")
    if options.kind == "object" and options.obj_id is None:
        raise PegasusError("an object scan needs --obj-id (an integer >= 1)")
    if (library.root / options.name).exists() and not options.overwrite:
        raise PegasusError(f"{library.root / options.name}: already exists (pass --overwrite to replace it)")
    if options.scale is None and options.aruco_size is None:
        raise PegasusError("metric scale needs --aruco-size (printed marker edge in metres) or --scale "
                           "(metres per reconstruction unit)")
    if options.scale is not None and not options.scale > 0:
        raise PegasusError(f"--scale must be positive, got {options.scale}")
    if options.second_images is not None and (options.kind != "object" or options.masks is None
                                              or options.second_masks is None):
        raise PegasusError("a two-part object scan (--second-images) needs --masks and --second-masks: the "
                           "object moved against the board between the halves, so only its pixels can be matched")
    for folder, photos in ((options.masks, names), (options.second_masks, None)):
        if folder is None:
            continue
        photos = photos if photos is not None else sfm.list_images(options.second_images)
        missing = [n for n in photos if _mask_path(Path(folder), n) is None]
        if missing:
            raise PegasusError(f"{folder}: no mask for {len(missing)} photo(s), e.g. {missing[0]} "
                               "(masks are named like the photos, .png allowed)")


def _mask_path(mask_dir: Path, name: str) -> Path | None:
    for candidate in (mask_dir / name, mask_dir / (name + ".png"), mask_dir / (Path(name).stem + ".png")):
        if candidate.is_file():
            return candidate
    return None


def camera_model(camera) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV K [3, 3] (pixel centres at integers) and distortion coefficients [4] of a pycolmap camera."""
    p = np.asarray(camera.params, np.float64)
    name = camera.model.name
    if name == "SIMPLE_PINHOLE":
        f, cx, cy, dist = p[0], p[1], p[2], np.zeros(4)
        fx = fy = f
    elif name == "PINHOLE":
        fx, fy, cx, cy, dist = p[0], p[1], p[2], p[3], np.zeros(4)
    elif name == "SIMPLE_RADIAL":
        fx = fy = p[0]
        cx, cy, dist = p[1], p[2], np.array([p[3], 0, 0, 0])
    elif name == "RADIAL":
        fx = fy = p[0]
        cx, cy, dist = p[1], p[2], np.array([p[3], p[4], 0, 0])
    elif name == "OPENCV":
        fx, fy, cx, cy, dist = p[0], p[1], p[2], p[3], p[4:8]
    else:
        raise PegasusError(f"camera model {name} is not supported for splat training")
    return np.array([[fx, 0, cx - 0.5], [0, fy, cy - 0.5], [0, 0, 1]]), dist


def training_image(path: Path, K: np.ndarray, dist: np.ndarray, size: int, interpolation=cv2.INTER_AREA
                   ) -> tuple[np.ndarray, np.ndarray]:
    """A photo undistorted and shrunk so its longest side is at most ``size``: (image [h, w, 3] float32 in
    [0, 1] (or [h, w] for a grey mask), K' [3, 3] of the shrunk pinhole image)."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise PegasusError(f"{path}: cannot read this image")
    if image.ndim == 3:
        image = cv2.cvtColor(image[..., :3], cv2.COLOR_BGR2RGB)
    if np.any(dist):
        image = cv2.undistort(image, K, dist)
    h, w = image.shape[:2]
    f = min(1.0, size / max(h, w))
    new_w, new_h = max(1, round(w * f)), max(1, round(h * f))
    if (new_w, new_h) != (w, h):
        image = cv2.resize(image, (new_w, new_h), interpolation=interpolation)
    sx, sy = new_w / w, new_h / h
    K_new = np.array([[K[0, 0] * sx, 0, (K[0, 2] + 0.5) * sx - 0.5], [0, K[1, 1] * sy, (K[1, 2] + 0.5) * sy - 0.5],
                      [0, 0, 1]])
    return image.astype(np.float32) / (65535.0 if image.dtype == np.uint16 else 255.0), K_new


def similarity_matrix(scale: float, T: np.ndarray) -> np.ndarray:
    """[4, 4] x -> T (scale x) for a rigid T [4, 4]."""
    S = np.array(T, dtype=np.float64)
    S[:3, :3] = S[:3, :3] * scale
    return S


def camera_in_frame(T_cam_rec: np.ndarray, S_frame_rec: np.ndarray) -> np.ndarray:
    """T_cam_frame [4, 4] of a camera given in the reconstruction frame, for the frame reached by the
    similarity S_frame_rec (x_frame = s R x_rec + t). The camera's own frame is scaled by s with the scene,
    which leaves its images unchanged."""
    s = np.cbrt(np.linalg.det(S_frame_rec[:3, :3]))
    R, t = S_frame_rec[:3, :3] / s, S_frame_rec[:3, 3]
    T = np.eye(4)
    T[:3, :3] = T_cam_rec[:3, :3] @ R.T
    T[:3, 3] = s * T_cam_rec[:3, 3] - T[:3, :3] @ t
    return T


def align_to_support_plane(points: np.ndarray, camera_centres: np.ndarray, kind: str,
                           rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    """Rigid T [4, 4] taking metric points [N, 3] to the asset frame: support plane (RANSAC) at z = 0 with
    the cameras [M, 3] above it; an object's point cluster above the plane centred over the origin.
    Returns (T, report: plane inliers, normal in the input frame, object extent)."""
    T, on_plane = support_plane_alignment(points, rng)
    centres = camera_centres @ T[:3, :3].T + T[:3, 3]
    if np.median(centres[:, 2]) < 0:  # photos are taken from above the support: flip about x
        T = np.diag([1.0, -1.0, -1.0, 1.0]) @ T
    report = {"plane_inliers": int(on_plane.sum()), "points": len(points),
              "plane_normal_input_frame": (T[2, :3]).tolist()}
    if kind == "object":
        aligned = points @ T[:3, :3].T + T[:3, 3]
        above = aligned[aligned[:, 2] > OBJECT_MIN_HEIGHT]
        if len(above) < 10:
            raise PegasusError(f"only {len(above)} reconstructed points stand above the support plane: no "
                               "object found on it (is the object textured and in most photos?)")
        labels = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(above)).cluster_dbscan(
            eps=OBJECT_CLUSTER_EPS, min_points=5))
        if labels.max() < 0:
            raise PegasusError("the points above the support plane form no cluster: no object found on it")
        cluster = above[labels == np.bincount(labels[labels >= 0]).argmax()]
        centre = np.median(cluster[:, :2], axis=0)
        T[:2, 3] -= centre
        radius = float(np.percentile(np.linalg.norm(cluster[:, :2] - centre, axis=1), 98))
        report.update(object_points=len(cluster), object_radius=radius,
                      object_height=float(np.percentile(cluster[:, 2], 99)))
    return T, report


def object_crop(points: np.ndarray, radius: float, height: float) -> np.ndarray:
    """[N] bool: which points [N, 3] (asset frame) belong to the object standing at the origin: above the
    support plane, inside the cylinder of the object's extent plus a margin."""
    r = np.linalg.norm(points[:, :2], axis=1)
    return (points[:, 2] > CROP_MIN_HEIGHT) & (points[:, 2] < height + 2 * OBJECT_MARGIN) & \
        (r < radius + OBJECT_MARGIN)


def _preview(path: Path, cloud: SplatCloud, views, device: str, count: int = 4, size: int = 320) -> None:
    """Held-out photos (top) above renders of the trained splats from the same cameras (bottom), each
    shown with its longest side ``size`` pixels."""
    from pegasus_gen.render.renderer import render

    columns = []
    for view in views[:count]:
        h, w = view.image.shape[:2]
        f = size / max(h, w)
        W, H = round(w * f), round(h * f)
        K = np.diag([W / w, H / h, 1.0]) @ view.K
        K[:2, 2] = (view.K[:2, 2] + 0.5) * [W / w, H / h] - 0.5
        out = render(cloud, K, view.T_cam_world, W, H, device=device)
        photo = cv2.resize(rgb_to_uint8(view.image), (W, H), interpolation=cv2.INTER_LINEAR)
        columns.append(np.concatenate([photo, rgb_to_uint8(out.rgb)], axis=0))
    if columns:
        write_image(path, np.concatenate(columns, axis=1))


def fit_similarity(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares similarity S [4, 4] with dst ~ S src (Umeyama) for corresponding points [N, 3], N >= 3."""
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - ms, dst - md
    U, D, Vt = np.linalg.svd(b.T @ a / len(src))
    flip = np.diag([1.0, 1.0, -1.0 if np.linalg.det(U) * np.linalg.det(Vt) < 0 else 1.0])
    R = U @ flip @ Vt
    c = float(np.trace(np.diag(D) @ flip) / a.var(axis=0).sum())
    S = np.eye(4)
    S[:3, :3] = c * R
    S[:3, 3] = md - c * R @ ms
    return S


def _link(source: Path, target: Path) -> None:
    try:
        target.symlink_to(source.resolve())
    except OSError:  # file systems without symlinks
        shutil.copyfile(source, target)


def register_second_half(rec: sfm.SfmResult, S_frame_rec: np.ndarray, options: ScanOptions, work_dir: Path
                         ) -> tuple[dict, np.ndarray, np.ndarray, dict]:
    """Place the photos of the turned-over object (``options.second_images``) in the first half's frame.

    Both halves go through one SfM with features only inside the object masks (the object is the one
    rigid thing both halves share); the first-half photos registered in both reconstructions give the
    similarity between them (camera centres, least squares). Returns (name -> (pycolmap camera,
    T_cam_frame [4, 4]) for the registered second-half photos, object points [N, 3] in the frame, their colours [N, 3], report).
    """
    first_dir, second_dir = rec.image_dir, Path(options.second_images)
    second_names = sfm.list_images(second_dir)
    combined = work_dir / "halves"
    if combined.exists():
        shutil.rmtree(combined)
    (combined / "images").mkdir(parents=True)
    (combined / "masks").mkdir()
    for prefix, folder, mask_folder, names in (("first_", first_dir, options.masks, rec.input_names),
                                               ("second_", second_dir, options.second_masks, second_names)):
        for name in names:
            _link(folder / name, combined / "images" / (prefix + name))
            _link(_mask_path(Path(mask_folder), name), combined / "masks" / (prefix + name + ".png"))
    both = sfm.reconstruct(combined / "images", work_dir / "sfm_halves", matcher=options.matcher,
                           intrinsics=options.intrinsics, mask_dir=combined / "masks", seed=options.seed, log=_log)
    registered = set(both.registered)
    shared = [n for n in rec.registered if "first_" + n in registered]
    placed = [n for n in second_names if "second_" + n in registered]
    report = {"shared_first_half_photos": len(shared), "second_half_photos": len(second_names),
              "second_half_registered": len(placed), "sfm": both.report()}
    if len(shared) < 3 or len(placed) < 3:
        raise PegasusError(f"{second_dir}: the turned-over half could not be joined to the first: "
                           f"{len(placed)} of {len(second_names)} of its photos and {len(shared)} first-half photos "
                           "were placed by object features alone. Photograph the object larger in the frame, "
                           "with views of its sides in both halves")

    def centre(T):
        return -T[:3, :3].T @ T[:3, 3]

    src = np.array([centre(both.T_cam_world("first_" + n)) for n in shared])
    dst = np.array([centre(camera_in_frame(rec.T_cam_world(n), S_frame_rec)) for n in shared])
    S = fit_similarity(src, dst)
    report["shared_camera_residual_m"] = float(np.abs(src @ S[:3, :3].T + S[:3, 3] - dst).max())
    cameras = {n: (both.camera("second_" + n), camera_in_frame(both.T_cam_world("second_" + n), S)) for n in placed}
    points, colours = both.points()
    return cameras, points @ S[:3, :3].T + S[:3, 3], colours, report


def training_views(photos, size: int) -> list:
    """TrainViews from (photo path, mask path or None, pycolmap camera, T_cam_frame [4, 4]) tuples: each
    photo (and mask) undistorted to a pinhole image with its longest side at most ``size`` pixels."""
    from pegasus_gen.scan.training import TrainView

    views = []
    for path, mask_path, camera, T in photos:
        K, dist = camera_model(camera)
        image, K_train = training_image(path, K, dist, size)
        mask = None
        if mask_path is not None:
            mask, _ = training_image(mask_path, K, dist, size, interpolation=cv2.INTER_LINEAR)
            mask = mask if mask.ndim == 2 else mask[..., 0]
        views.append(TrainView(image=image, K=K_train, T_cam_world=np.asarray(T, np.float64), mask=mask,
                               name=path.name))
    return views


def metric_frame(rec: sfm.SfmResult, detections: dict, options: ScanOptions, rng: np.random.Generator
                 ) -> tuple[np.ndarray, dict, dict]:
    """The similarity S [4, 4] from the reconstruction to the scan frame (metres, support plane z = 0,
    z up, an object over the origin), with the scale report and the alignment report."""
    if options.scale is not None:
        scale, scale_report = options.scale, {"scale_m_per_unit": options.scale, "source": "--scale"}
    else:
        corners = scan_markers.triangulate_markers(rec, detections)
        scale, scale_report = scan_markers.metric_scale(corners, options.aruco_size)
        scale_report["source"] = "aruco"
        _log(f"      scale {scale:.5g} m/unit from {scale_report['edges']} marker edges "
             f"(spread {100 * scale_report['relative_std']:.2f}%)")
    points, _ = rec.points()
    centres = np.array([np.linalg.inv(rec.T_cam_world(n))[:3, 3] for n in rec.registered])
    T_align, alignment = align_to_support_plane(points * scale, centres * scale, options.kind, rng)
    S = T_align @ similarity_matrix(scale, np.eye(4))
    alignment["S_frame_reconstruction"] = S.tolist()
    return S, scale_report, alignment


def _train_config(options: ScanOptions):
    from pegasus_gen.scan.training import SplatTrainConfig

    config = SplatTrainConfig.preset(options.preset)
    return config if options.iterations is None else config.model_copy(update={"iterations": options.iterations})


def run_scan(image_dir: str | Path, work_dir: str | Path, options: ScanOptions,
             library: AssetLibrary | None = None) -> dict:
    """Photos in ``image_dir`` -> asset ``options.name`` in ``library``; returns the scan report (also
    written to ``work_dir``/scan_report.json). Raises PegasusError with a clear message on bad input."""
    image_dir, work_dir = Path(image_dir), Path(work_dir)
    library = library or AssetLibrary()
    names = sfm.list_images(image_dir)
    _check_options(options, image_dir, names, library)
    rng = np.random.default_rng(options.seed)
    work_dir.mkdir(parents=True, exist_ok=True)
    report: dict = {"options": asdict(options), "images": len(names), "timings_s": {}}
    t0 = time.perf_counter()

    detections = {}
    if options.scale is None:
        _log(f"[1/5] ArUco markers ({options.aruco_dict}) in {len(names)} photos")
        detections = scan_markers.detect_in_folder(image_dir, names, options.aruco_dict)
        seen = sum(len(d) > 0 for d in detections.values())
        if seen == 0:
            raise PegasusError(f"{image_dir}: no {options.aruco_dict} ArUco markers in any of the {len(names)} "
                               "photos: metric scale is impossible. Put printed markers beside the object "
                               "(--aruco-dict to pick their dictionary) or give --scale")
        report["marker_detections"] = {"photos_with_markers": seen,
                                       "markers": sorted({i for d in detections.values() for i in d})}
    report["timings_s"]["markers"] = time.perf_counter() - t0

    _log(f"[2/5] structure from motion ({options.matcher} matching)")
    t = time.perf_counter()
    rec = sfm.reconstruct(image_dir, work_dir / "sfm", names, matcher=options.matcher,
                          intrinsics=options.intrinsics, seed=options.seed, log=_log)
    report["sfm"] = rec.report()
    report["timings_s"]["sfm"] = time.perf_counter() - t
    registered = rec.registered
    if len(registered) < 3 or len(registered) < MIN_REGISTERED_FRACTION * len(names):
        raise PegasusError(f"{image_dir}: only {len(registered)} of {len(names)} photos could be placed by "
                           "structure from motion: too few, or unrelated photos. Take photos that overlap "
                           "(each sharing most of its view with the next)")
    _log(f"      registered {len(registered)}/{len(names)} photos, {report['sfm']['points']} points, "
         f"reprojection error {report['sfm']['mean_reprojection_error_px']:.2f} px")

    _log("[3/5] metric scale and alignment")
    S, report["scale"], report["alignment"] = metric_frame(rec, detections, options, rng)
    scale = report["scale"]["scale_m_per_unit"]
    points, colours = rec.points()
    report["cameras_T_cam_frame"] = {n: camera_in_frame(rec.T_cam_world(n), S).tolist() for n in registered}

    aligned = points @ S[:3, :3].T + S[:3, 3]
    masks = Path(options.masks) if options.masks is not None else None
    # (photo, its mask or None, pycolmap camera, T_cam_frame) for every registered photo
    photos = [(image_dir / n, masks and _mask_path(masks, n), rec.camera(n), report["cameras_T_cam_frame"][n])
              for n in registered]
    if options.second_images is not None:
        _log("      joining the turned-over half (object features only)")
        cameras, points_b, colours_b, report["second_half"] = register_second_half(rec, S, options, work_dir)
        second, second_masks = Path(options.second_images), Path(options.second_masks)
        photos += [(second / n, _mask_path(second_masks, n), cam, T) for n, (cam, T) in cameras.items()]
        report["cameras_T_cam_frame"].update({f"second/{n}": T.tolist() for n, (_, T) in cameras.items()})
        aligned, colours = np.concatenate([aligned, points_b]), np.concatenate([colours, colours_b])
        _log(f"      placed {len(cameras)} of its photos (shared cameras agree within "
             f"{1000 * report['second_half']['shared_camera_residual_m']:.1f} mm)")

    _log(f"[4/5] Gaussian-splat training on {len(photos)} photos")
    from pegasus_gen.scan.training import init_from_points, train_splats

    t = time.perf_counter()
    views = training_views(photos, options.train_size or TRAIN_SIZE[options.preset])
    held_out = views[options.holdout_every - 1::options.holdout_every] if len(views) >= 2 * options.holdout_every \
        else []
    train_views = [v for v in views if all(v is not h for h in held_out)]
    keep = np.ones(len(aligned), bool)
    if options.kind == "object" and masks is not None:  # the photos show the object alone
        a = report["alignment"]
        keep = object_crop(aligned, a["object_radius"], a["object_height"])
    cloud, train_report = train_splats(init_from_points(aligned[keep], colours[keep]), train_views, held_out,
                                       _train_config(options), device=options.device)
    losses = np.asarray(train_report.pop("loss_history"))
    write_image(work_dir / "training_loss.png", line_chart(
        {"L1 + SSIM loss": (np.arange(1, len(losses) + 1), losses)}, "splat training", "iteration", "loss",
        log_y=True))
    report["training"] = train_report
    report["timings_s"]["training"] = time.perf_counter() - t
    write_ply(work_dir / "splats_aligned.ply", cloud)
    _preview(work_dir / "preview.png", cloud, held_out or train_views, options.device)

    _log("[5/5] asset")
    if options.kind == "object":
        a = report["alignment"]
        cloud = cloud.select(object_crop(cloud.means, a["object_radius"], a["object_height"]))
        if len(cloud) < 50:
            raise PegasusError(f"only {len(cloud)} trained splats lie on the object: the scan is too sparse")
    geometry = {"source": "pegasus scan", "images": len(names), "registered": len(registered),
                "scale_m_per_unit": scale, "psnr_held_out": train_report.get("psnr_test")}
    asset = import_cloud(cloud, options.name, options.kind, library, options.obj_id, rng,
                         overwrite=options.overwrite, geometry=geometry)
    report["asset"] = str(asset.path)
    report["timings_s"]["total"] = time.perf_counter() - t0
    (work_dir / "scan_report.json").write_text(json.dumps(report, indent=1, default=_json_default))
    _log(f"asset written: {asset.path} ({len(asset.splats):,} splats); report: {work_dir / 'scan_report.json'}")
    return report


def _json_default(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return str(value)

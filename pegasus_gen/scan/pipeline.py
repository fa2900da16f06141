"""The scan pipeline: a folder of photos -> a metric, z-up Gaussian-splat asset in the library.

Steps (``run_scan``): :func:`find_markers` (ArUco detection; fails early when metric scale is impossible) ->
:func:`structure_from_motion` (:mod:`pegasus_gen.scan.sfm`) -> :func:`metric_frame` (scale from the markers,
:mod:`pegasus_gen.scan.markers`; support plane by RANSAC to z = 0, z up; an object centred over the origin) ->
:func:`posed_photos` (with the turned-over half of a two-part object scan) -> :func:`train_scene` (3DGS
training, :mod:`pegasus_gen.scan.training`) -> :func:`write_asset` (cropped to the object; through
:func:`pegasus_gen.assets.importers.import_cloud`: collision mesh, URDF, manifest).

Everything except the asset goes to the work folder (``WORK_FILES``): ``sfm/`` (COLMAP database and model;
``halves/`` and ``sfm_halves/`` for a two-part scan), ``splats_aligned.ply`` (the trained scene, metric z-up),
``scan_report.json`` (a :class:`ScanReport`), ``training_loss.png`` and ``preview.png`` (held-out photos above
their renders). A scan deletes and overwrites nothing it did not make: it refuses a work folder that already
holds any of these, and a failed scan leaves the ones it wrote for inspection. The asset is written last, so a
failure leaves no asset. Progress goes to the ``logging`` module (INFO).
"""

from __future__ import annotations

import logging
import shutil
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from pegasus_gen.assets.importers import import_cloud
from pegasus_gen.assets.library import Asset, AssetLibrary, check_new_asset
from pegasus_gen.errors import PegasusError
from pegasus_gen.io.images import rgb_to_uint8, write_image
from pegasus_gen.io.plots import line_chart
from pegasus_gen.scan import markers as scan_markers
from pegasus_gen.scan import sfm
from pegasus_gen.scan.frame import (
    align_to_support_plane,
    camera_in_frame,
    fit_similarity,
    object_crop,
    similarity_matrix,
)
from pegasus_gen.scan.options import ScanOptions
from pegasus_gen.scan.report import ScanReport, ScanTimings
from pegasus_gen.splats.cloud import SplatCloud
from pegasus_gen.splats.ply import write_ply

logger = logging.getLogger(__name__)

MIN_REGISTERED_FRACTION = 0.5  # below this the photos are too unrelated to trust the reconstruction
WORK_FILES = ("sfm", "halves", "sfm_halves", "splats_aligned.ply", "scan_report.json", "training_loss.png",
              "preview.png")  # what a scan writes in its work folder


def check_inputs(options: ScanOptions, names: list[str], library: AssetLibrary) -> None:
    """Refuse what the options cannot check alone: an asset of that name already in ``library`` (without
    ``overwrite``), photos (``names``, and the second half's) without a mask in the mask folders."""
    check_new_asset(library, options.name, options.kind, options.obj_id, options.overwrite)
    for folder, photos in ((options.masks, names), (options.second_masks, None)):
        if folder is None:
            continue
        photos = photos if photos is not None else sfm.list_images(options.second_images)
        missing = [n for n in photos if _mask_path(Path(folder), n) is None]
        if missing:
            raise PegasusError(f"{folder}: no mask for {len(missing)} photo(s), e.g. {missing[0]} "
                               "(masks are named like the photos, .png allowed)")


def check_work_folder(work_dir: Path) -> None:
    """Refuse a ``work_dir`` that is not a folder, or that holds any of ``WORK_FILES`` (an earlier scan's, or
    someone's): a scan replaces nothing it did not make."""
    if work_dir.exists() and not work_dir.is_dir():
        raise PegasusError(f"{work_dir}: exists and is not a folder (--work)")
    found = [name for name in WORK_FILES if (work_dir / name).exists() or (work_dir / name).is_symlink()]
    if found:
        raise PegasusError(f"{work_dir} already holds {', '.join(found)} (an earlier scan's?); a scan replaces "
                           "nothing it did not make: remove them or choose another --work")


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
    T_cam_frame [4, 4]) for the registered second-half photos, object points [N, 3] in the frame, their
    colours [N, 3], report).
    """
    first_dir, second_dir = rec.image_dir, Path(options.second_images)
    second_names = sfm.list_images(second_dir)
    combined = work_dir / "halves"  # new: run_scan refuses a work folder that holds one
    (combined / "images").mkdir(parents=True)
    (combined / "masks").mkdir()
    for prefix, folder, mask_folder, names in (("first_", first_dir, options.masks, rec.input_names),
                                               ("second_", second_dir, options.second_masks, second_names)):
        for name in names:
            _link(folder / name, combined / "images" / (prefix + name))
            _link(_mask_path(Path(mask_folder), name), combined / "masks" / (prefix + name + ".png"))
    both = sfm.reconstruct(combined / "images", work_dir / "sfm_halves", matcher=options.matcher,
                           intrinsics=options.intrinsics, mask_dir=combined / "masks", seed=options.seed)
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


def find_markers(image_dir: Path, names: list[str], options: ScanOptions) -> tuple[dict, dict | None]:
    """Step 1: the ArUco markers in the photos (photo name -> {marker id -> corners [4, 2] px}) and a report
    (photos with markers, marker ids); ({}, None) when the options give the scale."""
    if options.scale is not None:
        return {}, None
    logger.info("[1/5] ArUco markers (%s) in %d photos", options.aruco_dict, len(names))
    detections = scan_markers.detect_in_folder(image_dir, names, options.aruco_dict)
    seen = sum(len(d) > 0 for d in detections.values())
    if seen == 0:
        raise PegasusError(f"{image_dir}: no {options.aruco_dict} ArUco markers in any of the {len(names)} "
                           "photos: metric scale is impossible. Put printed markers beside the object "
                           "(--aruco-dict to pick their dictionary) or give --scale")
    return detections, {"photos_with_markers": seen, "markers": sorted({i for d in detections.values() for i in d})}


def structure_from_motion(image_dir: Path, work_dir: Path, names: list[str], options: ScanOptions
                          ) -> tuple[sfm.SfmResult, dict]:
    """Step 2: SfM on the photos (into ``work_dir``/sfm), refused when too few of them are placed; returns
    (the reconstruction, its quality report)."""
    logger.info("[2/5] structure from motion (%s matching)", options.matcher)
    rec = sfm.reconstruct(image_dir, work_dir / "sfm", names, matcher=options.matcher,
                          intrinsics=options.intrinsics, seed=options.seed)
    registered = rec.registered
    if len(registered) < 3 or len(registered) < MIN_REGISTERED_FRACTION * len(names):
        raise PegasusError(f"{image_dir}: only {len(registered)} of {len(names)} photos could be placed by "
                           "structure from motion: too few, or unrelated photos. Take photos that overlap "
                           "(each sharing most of its view with the next)")
    quality = rec.report()
    logger.info("      registered %d/%d photos, %d points, reprojection error %.2f px", len(registered), len(names),
                quality["points"], quality["mean_reprojection_error_px"])
    return rec, quality


def metric_frame(rec: sfm.SfmResult, detections: dict, options: ScanOptions, rng: np.random.Generator
                 ) -> tuple[np.ndarray, dict, dict]:
    """Step 3: the similarity S [4, 4] from the reconstruction to the scan frame (metres, support plane z = 0,
    z up, an object over the origin), with the scale report and the alignment report."""
    logger.info("[3/5] metric scale and alignment")
    if options.scale is not None:
        scale, scale_report = options.scale, {"scale_m_per_unit": options.scale, "source": "--scale"}
    else:
        corners = scan_markers.triangulate_markers(rec, detections)
        scale, scale_report = scan_markers.metric_scale(corners, options.aruco_size)
        scale_report["source"] = "aruco"
        logger.info("      scale %.5g m/unit from %d marker edges (spread %.2f%%)", scale, scale_report["edges"],
                    100 * scale_report["relative_std"])
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


@dataclass
class PosedPhotos:
    """The photos placed in the scan frame, and the SfM points there: what splat training starts from."""

    photos: list  # (photo path, its mask path or None, pycolmap camera, T_cam_frame [4, 4]) per placed photo
    points: np.ndarray  # [N, 3] m, scan frame
    colours: np.ndarray  # [N, 3] in [0, 1]
    cameras_T_cam_frame: dict  # photo name ("second/NAME": the turned-over half) -> T_cam_frame [4, 4] (lists)
    second_half: dict | None = None  # register_second_half's report; None for a one-part scan


def posed_photos(rec: sfm.SfmResult, S: np.ndarray, options: ScanOptions, work_dir: Path) -> PosedPhotos:
    """The registered photos (and the turned-over half's, for a two-part object scan) with their masks,
    cameras and the SfM points in the scan frame that the similarity S [4, 4] maps the reconstruction to."""
    points, colours = rec.points()
    cameras = {n: camera_in_frame(rec.T_cam_world(n), S).tolist() for n in rec.registered}
    masks = Path(options.masks) if options.masks is not None else None
    photos = [(rec.image_dir / n, masks and _mask_path(masks, n), rec.camera(n), T) for n, T in cameras.items()]
    posed = PosedPhotos(photos, points @ S[:3, :3].T + S[:3, 3], colours, cameras)
    if options.second_images is None:
        return posed
    logger.info("      joining the turned-over half (object features only)")
    placed, points_b, colours_b, posed.second_half = register_second_half(rec, S, options, work_dir)
    second, second_masks = Path(options.second_images), Path(options.second_masks)
    posed.photos += [(second / n, _mask_path(second_masks, n), cam, T) for n, (cam, T) in placed.items()]
    posed.cameras_T_cam_frame.update({f"second/{n}": T.tolist() for n, (_, T) in placed.items()})
    posed.points, posed.colours = np.concatenate([posed.points, points_b]), np.concatenate([posed.colours, colours_b])
    logger.info("      placed %d of its photos (shared cameras agree within %.1f mm)", len(placed),
                1000 * posed.second_half["shared_camera_residual_m"])
    return posed


def train_scene(posed: PosedPhotos, alignment: dict, options: ScanOptions, work_dir: Path) -> tuple[SplatCloud, dict]:
    """Step 4: 3DGS training on the posed photos (every ``holdout_every``-th held out for PSNR when there are
    enough), started from the SfM points (an object scan with masks: those on the object). Writes
    splats_aligned.ply, training_loss.png and preview.png to ``work_dir``; returns (the trained splats, the
    training report without its loss history)."""
    from pegasus_gen.scan.training import init_from_points, train_splats

    logger.info("[4/5] Gaussian-splat training on %d photos", len(posed.photos))
    views = training_views(posed.photos, options.training_size)
    every = options.holdout_every
    held_out = views[every - 1::every] if len(views) >= 2 * every else []
    train_views = [v for v in views if all(v is not h for h in held_out)]
    keep = np.ones(len(posed.points), bool)
    if options.kind == "object" and options.masks is not None:  # the photos show the object alone
        keep = object_crop(posed.points, alignment["object_radius"], alignment["object_height"])
    cloud, report = train_splats(init_from_points(posed.points[keep], posed.colours[keep]), train_views, held_out,
                                 _train_config(options), device=options.device)
    losses = np.asarray(report.pop("loss_history"))
    write_image(work_dir / "training_loss.png", line_chart(
        {"L1 + SSIM loss": (np.arange(1, len(losses) + 1), losses)}, "splat training", "iteration", "loss",
        log_y=True))
    write_ply(work_dir / "splats_aligned.ply", cloud)
    _preview(work_dir / "preview.png", cloud, held_out or train_views, options.device)
    return cloud, report


def write_asset(cloud: SplatCloud, alignment: dict, options: ScanOptions, library: AssetLibrary,
                rng: np.random.Generator, geometry: dict) -> Asset:
    """Step 5: the trained splats (an object's cropped to it) as asset ``options.name`` in ``library``, with
    ``geometry`` (provenance and quality figures) in its manifest."""
    logger.info("[5/5] asset")
    if options.kind == "object":
        cloud = cloud.select(object_crop(cloud.means, alignment["object_radius"], alignment["object_height"]))
        if len(cloud) < 50:
            raise PegasusError(f"only {len(cloud)} trained splats lie on the object: the scan is too sparse")
    return import_cloud(cloud, options.name, options.kind, library, options.obj_id, rng,
                        overwrite=options.overwrite, geometry=geometry)


def run_scan(image_dir: str | Path, work_dir: str | Path, options: ScanOptions,
             library: AssetLibrary | None = None) -> ScanReport:
    """Photos in ``image_dir`` -> asset ``options.name`` in ``library``; returns the scan report (also
    written to ``work_dir``/scan_report.json; ``check_work_folder`` says which work folders are refused).
    Raises PegasusError with a clear message on bad input."""
    image_dir, work_dir = Path(image_dir), Path(work_dir)
    library = library or AssetLibrary()
    names = sfm.list_images(image_dir)
    check_inputs(options, names, library)
    check_work_folder(work_dir)
    rng = np.random.default_rng(options.seed)
    timings = ScanTimings()
    with timings.timed("total"):
        with timings.timed("markers"):
            detections, marker_report = find_markers(image_dir, names, options)
        work_dir.mkdir(parents=True, exist_ok=True)
        with timings.timed("sfm"):
            rec, quality = structure_from_motion(image_dir, work_dir, names, options)
        S, scale, alignment = metric_frame(rec, detections, options, rng)
        posed = posed_photos(rec, S, options, work_dir)
        with timings.timed("training"):
            cloud, training = train_scene(posed, alignment, options, work_dir)
        asset = write_asset(cloud, alignment, options, library, rng, geometry={
            "source": "pegasus scan", "images": len(names), "registered": len(rec.registered),
            "scale_m_per_unit": scale["scale_m_per_unit"], "psnr_held_out": training.get("psnr_test")})
    report = ScanReport(options=options.model_dump(), images=len(names), timings_s=timings,
                        marker_detections=marker_report, sfm=quality, scale=scale, alignment=alignment,
                        cameras_T_cam_frame=posed.cameras_T_cam_frame, second_half=posed.second_half,
                        training=training, asset=str(asset.path))
    path = report.write(work_dir / "scan_report.json")
    logger.info("asset written: %s (%s splats); report: %s", asset.path, f"{len(asset.splats):,}", path)
    return report

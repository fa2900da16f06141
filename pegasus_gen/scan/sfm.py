"""Structure from motion with pycolmap: SIFT features, matching, incremental mapping, quality report.

The reconstruction is in COLMAP's arbitrary frame and scale; :mod:`pegasus_gen.scan.markers` makes it
metric and :mod:`pegasus_gen.scan.pipeline` aligns it. Camera poses are returned in this project's convention,
T_cam_world [4, 4] (world -> OpenCV camera), intrinsics as K [3, 3] in pixels of the input images.
"""

from __future__ import annotations

import logging
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pycolmap

from pegasus_gen.errors import PegasusError

logger = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
MATCHERS = ("exhaustive", "sequential")


def list_images(folder: str | Path) -> list[str]:
    """Sorted image file names (not paths) in ``folder``; a clear error if it holds none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise PegasusError(f"{folder}: not a folder of images")
    names = sorted(p.name for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not names:
        raise PegasusError(f"{folder}: no images ({', '.join(IMAGE_SUFFIXES)})")
    return names


@dataclass
class SfmResult:
    """A pycolmap reconstruction with the names of every input image and plain-array accessors."""

    reconstruction: pycolmap.Reconstruction
    image_dir: Path
    input_names: list[str]

    @property
    def registered(self) -> list[str]:
        """Names of the registered images, sorted."""
        return sorted(img.name for img in self.reconstruction.images.values() if img.has_pose)

    def image(self, name: str) -> pycolmap.Image:
        for img in self.reconstruction.images.values():
            if img.name == name:
                return img
        raise KeyError(name)

    def T_cam_world(self, name: str) -> np.ndarray:
        """World (reconstruction frame) -> camera [4, 4] of a registered image."""
        T = np.eye(4)
        T[:3, :] = self.image(name).cam_from_world().matrix()
        return T

    def camera(self, name: str) -> pycolmap.Camera:
        return self.reconstruction.cameras[self.image(name).camera_id]

    def points(self, min_track: int = 2) -> tuple[np.ndarray, np.ndarray]:
        """3D points [N, 3] (reconstruction frame) and their colours [N, 3] in [0, 1], seen by >= min_track images."""
        pts = [p for p in self.reconstruction.points3D.values() if p.track.length() >= min_track]
        if not pts:
            return np.zeros((0, 3)), np.zeros((0, 3))
        return np.array([p.xyz for p in pts]), np.array([p.color for p in pts], np.float64) / 255.0

    def report(self) -> dict:
        """Quality figures: registered images (count, fraction, which are missing), points, mean
        reprojection error (pixels), mean track length."""
        rec = self.reconstruction
        registered = self.registered
        return {
            "images": len(self.input_names),
            "registered": len(registered),
            "registered_fraction": len(registered) / max(len(self.input_names), 1),
            "unregistered": sorted(set(self.input_names) - set(registered)),
            "points": rec.num_points3D(),
            "mean_reprojection_error_px": float(rec.compute_mean_reprojection_error()),
            "mean_track_length": float(rec.compute_mean_track_length()) if rec.num_points3D() else 0.0,
        }


def _reader_options(intrinsics, mask_dir) -> pycolmap.ImageReaderOptions:
    options = pycolmap.ImageReaderOptions()
    if intrinsics is not None:
        fx, fy, cx, cy = (float(v) for v in intrinsics)
        options.camera_model = "PINHOLE"
        # COLMAP puts pixel centres at +0.5; this project (OpenCV) at integers
        options.camera_params = f"{fx},{fy},{cx + 0.5},{cy + 0.5}"
    if mask_dir is not None:
        options.mask_path = str(mask_dir)
    return options


def reconstruct(image_dir: str | Path, work_dir: str | Path, names: list[str] | None = None,
                matcher: str = "exhaustive", intrinsics=None, mask_dir: str | Path | None = None,
                max_image_size: int = 1600, seed: int = 0) -> SfmResult:
    """Run SfM on the images of ``image_dir`` (all, or ``names``) and keep the largest reconstruction.

    work_dir: a new or empty folder; gets database.db and sparse/ (COLMAP's model files, written again after
    the run).
    matcher: "exhaustive" (every pair: small sets) or "sequential" (neighbours in name order plus
    loop detection off: large video-like sets, no vocabulary needed).
    intrinsics: (fx, fy, cx, cy) in pixels, OpenCV convention, when the camera is calibrated: one shared
    PINHOLE camera, kept fixed; otherwise one shared SIMPLE_RADIAL camera is estimated.
    mask_dir: COLMAP feature masks (``<image name>.png``, features where the mask is non-zero).
    Raises PegasusError when nothing or too little registers.
    """
    if matcher not in MATCHERS:
        raise PegasusError(f"matcher must be one of {MATCHERS}, got {matcher!r}")
    image_dir = Path(image_dir)
    names = list_images(image_dir) if names is None else list(names)
    if len(names) < 3:
        raise PegasusError(f"{image_dir}: {len(names)} image(s); structure from motion needs at least 3 "
                           "overlapping photos (a scan usually has 30-200)")
    work_dir = Path(work_dir)
    if work_dir.exists() and (not work_dir.is_dir() or any(work_dir.iterdir())):
        raise PegasusError(f"{work_dir}: exists and is not an empty folder; structure from motion writes a new "
                           "one (it deletes nothing it did not make)")
    (work_dir / "sparse").mkdir(parents=True)
    database = work_dir / "database.db"
    pycolmap.set_random_seed(seed)
    # COLMAP's own log (glog, per-image detail) only with `pegasus -v`
    pycolmap.logging.minloglevel = 0 if logging.getLogger().isEnabledFor(logging.DEBUG) else 1
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = max_image_size
    extraction.use_gpu = False
    logger.info("sfm: extracting features from %d images", len(names))
    pycolmap.extract_features(database, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=_reader_options(intrinsics, mask_dir), extraction_options=extraction,
                              device=pycolmap.Device.cpu)
    logger.info("sfm: %s matching", matcher)
    if matcher == "exhaustive":
        pycolmap.match_exhaustive(database, device=pycolmap.Device.cpu)
    else:
        pycolmap.match_sequential(database, device=pycolmap.Device.cpu)
    options = pycolmap.IncrementalPipelineOptions()
    options.random_seed = seed
    options.num_threads = -1
    if intrinsics is not None:  # a calibrated camera stays as given
        options.ba_refine_focal_length = False
        options.ba_refine_extra_params = False
        options.mapper.abs_pose_refine_focal_length = False
        options.mapper.abs_pose_refine_extra_params = False
    logger.info("sfm: incremental mapping")
    models = pycolmap.incremental_mapping(database, image_dir, work_dir / "sparse", options=options)
    if not models:
        raise PegasusError(f"{image_dir}: structure from motion registered no images: the photos do not "
                           "overlap enough (or are unrelated); take more photos, each sharing most of its "
                           "view with the next")
    best = max(models.values(), key=lambda r: r.num_reg_images())
    shutil.rmtree(work_dir / "sparse")
    (work_dir / "sparse").mkdir()
    best.write(work_dir / "sparse")
    return SfmResult(best, image_dir, names)

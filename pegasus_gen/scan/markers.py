"""Metric scale from ArUco markers: detect corners in every photo, triangulate them from the registered
cameras of the SfM reconstruction, scale so the markers' edges have their printed length.

Pixel convention here is OpenCV's (pixel centres at integers); pycolmap's cameras put them at +0.5,
which :func:`triangulate_markers` accounts for.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from pegasus_gen.errors import PegasusError
from pegasus_gen.scan.sfm import SfmResult

MIN_VIEWS = 2  # a corner needs at least this many views to be triangulated
MAX_REPROJECTION_PX = 2.0  # corners whose triangulation misses a view by more are dropped


def aruco_dictionary(name: str):
    """The cv2.aruco predefined dictionary called ``name`` (e.g. "DICT_4X4_50"), with a clear error."""
    value = getattr(cv2.aruco, name, None)
    if not name.startswith("DICT_") or not isinstance(value, int):
        known = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
        raise PegasusError(f"unknown ArUco dictionary {name!r}; choose one of: {', '.join(known)}")
    return cv2.aruco.getPredefinedDictionary(value)


def detect_markers(image: np.ndarray, dictionary: str) -> dict[int, np.ndarray]:
    """ArUco markers in one image (uint8 grey or RGB [H, W(, 3)]): marker id -> corners [4, 2] in pixels
    (sub-pixel refined, ArUco order). A marker id seen twice in one image is ambiguous and dropped."""
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(aruco_dictionary(dictionary), params)
    corners, ids, _ = detector.detectMarkers(grey)
    if ids is None:
        return {}
    ids = ids.ravel().tolist()
    return {i: c.reshape(4, 2).astype(np.float64) for i, c in zip(ids, corners) if ids.count(i) == 1}


def detect_in_folder(image_dir: str | Path, names: list[str], dictionary: str) -> dict[str, dict[int, np.ndarray]]:
    """detect_markers for each named image of a folder: image name -> {marker id -> corners [4, 2]}."""
    found = {}
    for name in names:
        image = cv2.imread(str(Path(image_dir) / name), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise PegasusError(f"{Path(image_dir) / name}: cannot read this image")
        found[name] = detect_markers(image, dictionary)
    return found


def _triangulate(rays: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """Linear (DLT) point [3] from (P [3, 4] normalised camera matrix, xy [2] normalised coordinates) pairs."""
    rows = []
    for P, (x, y) in rays:
        rows.append(x * P[2] - P[0])
        rows.append(y * P[2] - P[1])
    _, _, vt = np.linalg.svd(np.array(rows))
    X = vt[-1]
    return X[:3] / X[3]


def triangulate_markers(sfm: SfmResult, detections: dict[str, dict[int, np.ndarray]]
                        ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Marker corners in the reconstruction frame from their detections in the registered images.

    Returns marker id -> (corners [4, 3] with NaN rows for corners that could not be triangulated,
    views [4] number of images each corner was triangulated from).
    """
    registered = set(sfm.registered)
    obs: dict[int, list[list]] = {}
    for name, markers in detections.items():
        if name not in registered:
            continue
        camera = sfm.camera(name)
        T = sfm.T_cam_world(name)
        focal = camera.mean_focal_length()
        for marker_id, corners in markers.items():
            normalised = camera.cam_from_img(corners + 0.5)  # OpenCV -> COLMAP pixel centres
            per_corner = obs.setdefault(marker_id, [[], [], [], []])
            for k in range(4):
                per_corner[k].append((T[:3], normalised[k], focal))
    result = {}
    for marker_id, per_corner in obs.items():
        corners = np.full((4, 3), np.nan)
        views = np.zeros(4, int)
        for k, rays in enumerate(per_corner):
            if len(rays) < MIN_VIEWS:
                continue
            X = _triangulate([(P, xy) for P, xy, _ in rays])
            keep = []
            for P, xy, focal in rays:
                x_cam = P @ np.r_[X, 1.0]
                if x_cam[2] > 0 and focal * np.linalg.norm(x_cam[:2] / x_cam[2] - xy) < MAX_REPROJECTION_PX:
                    keep.append((P, xy))
            if len(keep) >= MIN_VIEWS:
                corners[k] = _triangulate(keep)
                views[k] = len(keep)
        result[marker_id] = (corners, views)
    return result


def metric_scale(corners: dict[int, tuple[np.ndarray, np.ndarray]], marker_size: float) -> tuple[float, dict]:
    """Metres per reconstruction unit from triangulated marker corners and the printed edge length
    ``marker_size`` (metres). Every marker edge with both corners triangulated gives one estimate; the
    scale is their median. Returns (scale, report with the spread: relative std, min, max, counts)."""
    if not marker_size > 0:
        raise PegasusError(f"the marker size must be positive (metres), got {marker_size}")
    estimates, used = [], []
    for marker_id, (c, _) in sorted(corners.items()):
        edges = [np.linalg.norm(c[k] - c[(k + 1) % 4]) for k in range(4)]
        edges = [e for e in edges if np.isfinite(e) and e > 0]
        if edges:
            used.append(marker_id)
            estimates.extend(marker_size / e for e in edges)
    if not estimates:
        raise PegasusError("ArUco markers were detected but none could be triangulated (each corner needs "
                           f"{MIN_VIEWS} registered views): metric scale impossible; photograph the markers "
                           "from more viewpoints, or give the scale")
    estimates = np.array(estimates)
    scale = float(np.median(estimates))
    return scale, {"scale_m_per_unit": scale, "markers": used, "edges": len(estimates),
                   "relative_std": float(estimates.std() / scale), "relative_min": float(estimates.min() / scale),
                   "relative_max": float(estimates.max() / scale)}

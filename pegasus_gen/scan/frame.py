"""The scan's metric, z-up frame: similarity transforms between a reconstruction and it, the support plane
found by RANSAC and turned to z = 0 (an object's points found above it), and the crop of an object's splats."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from pegasus_gen.assets.importers import support_plane_alignment
from pegasus_gen.errors import PegasusError

OBJECT_MIN_HEIGHT = 0.004  # m: SfM points this far above the support plane are candidates for the object
OBJECT_CLUSTER_EPS = 0.02  # m: DBSCAN neighbourhood joining object points into one cluster
OBJECT_MARGIN = 0.01  # m added around the object's extent when cropping the trained splats
CROP_MIN_HEIGHT = 0.002  # m: trained splats below this height belong to the support plane


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

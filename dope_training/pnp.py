"""Object pose from DOPE's 2D keypoints and the object's cuboid (Perspective-n-Point), robust to wrong keypoints.

Rule: the keypoints found (finite rows; the centroid counts like a corner) must number at least
``MIN_POINTS``. The pose is the global minimum of SQPnP (cv2.SOLVEPNP_SQPNP: any configuration of >= 3 points,
coplanar ones included, no initial guess), refined by Levenberg-Marquardt on the reprojection error
(cv2.solvePnPRefineLM). Then, while more than ``MIN_INLIERS`` keypoints are in use and the worst of them lies
farther from its reprojection than ``OUTLIER_FRACTION`` of the projected box's diagonal, that one is dropped
and the pose solved again: a misplaced corner peak, or a peak of another cup, another object or noise joined
to the instance, pulls the whole pose with it (on the held-out cups of ``docs/TRAINING.md`` DOPE's ADD-S AUC
rose by 0.13-0.36 for six networks). Solutions that put any cuboid point at or behind the camera plane are
rejected. Why 5: over 300 random poses of a 10 cm box at 0.4-0.9 m (f = 600 px), 4 exact keypoints gave a
wrong pose (up to 176 degrees off) for 1.7 % of them, and with 2 px noise a 95th-percentile rotation error of
12 degrees against 4.6 with 5 keypoints and 3.1 with all 9.

Consensus over candidate peaks (``solve_pose_consensus``): dropping outliers helps where a few keypoints are wrong,
not where most of them sit on look-alike parts of the object (a box's corners turned by 90 or 180 degrees). Each
corner's candidate peaks (``decode.corner_candidates``) then often hold the right one as a weaker peak. Hypotheses:
the keypoints as joined, and ``HYPOTHESES`` draws of ``SAMPLE`` corners, each with one of its candidates at random,
solved with the centroid by SQPnP alone; each scores the beliefs of the candidates lying within ``tau_px`` of its
reprojected corners (none if the centroid does not reproject within it), and the best one's keypoints are solved
as above. Draws are seeded: the same input gives the same pose.
"""

from __future__ import annotations

import cv2
import numpy as np

MIN_POINTS = 5
HYPOTHESES = 150  # consensus: drawn hypotheses per instance
SAMPLE = 5  # consensus: corners per drawn hypothesis (with the centroid)
MIN_INLIERS = 6  # keypoints kept at least when dropping outliers
OUTLIER_FRACTION = 0.15  # reprojection error beyond this share of the projected box's diagonal: an outlier


def solve_pose(keypoints_2d: np.ndarray, cuboid: np.ndarray, K: np.ndarray, dist: np.ndarray | None = None,
               min_points: int = MIN_POINTS) -> tuple[np.ndarray, float] | None:
    """T_cam_obj [4, 4] (metres, as ``cuboid``) and the mean reprojection error (px) of the keypoints used,
    or None when fewer than ``min_points`` are found, PnP fails or the object would be behind the camera.

    keypoints_2d [P, 2]: pixels (OpenCV), NaN rows for keypoints not found; cuboid [P, 3]: the same
    keypoints in the object frame (``cuboid.cuboid_points``, or the network's object points: the centre last);
    K [3, 3]; dist: OpenCV distortion or None.
    """
    used = np.isfinite(keypoints_2d).all(axis=1)
    if used.sum() < min_points:
        return None
    K = np.asarray(K, dtype=np.float64)
    while True:
        obj = np.ascontiguousarray(cuboid[used], dtype=np.float64)
        img = np.ascontiguousarray(keypoints_2d[used], dtype=np.float64)
        try:  # OpenCV asserts on degenerate input (keypoints that all coincide): no pose, like a failed solve
            ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_SQPNP)
            if not ok:
                return None
            rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, dist, rvec, tvec)
        except cv2.error:
            return None
        projected = cv2.projectPoints(np.asarray(cuboid, np.float64), rvec, tvec, K, dist)[0].reshape(-1, 2)
        errors = np.where(used, np.linalg.norm(projected - np.nan_to_num(keypoints_2d), axis=1), -1.0)
        worst = int(np.argmax(errors))
        diagonal = float(np.linalg.norm(np.ptp(projected[:-1], axis=0)))
        if used.sum() <= MIN_INLIERS or not errors[worst] > OUTLIER_FRACTION * diagonal:
            break
        used[worst] = False
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.ravel()
    if not np.isfinite(T).all() or ((cuboid @ T[:3, :3].T + T[:3, 3])[:, 2] <= 0).any():
        return None
    return T, float(errors[used].mean())


def _project(cuboid: np.ndarray, poses: list[tuple[np.ndarray, np.ndarray]], K: np.ndarray,
             dist: np.ndarray | None) -> np.ndarray:
    """[H, P, 2] px: ``cuboid`` [P, 3] projected at each pose (rvec [3, 1], tvec [3, 1]); NaN where a point lies at
    or behind the camera plane."""
    if dist is not None and np.any(dist):
        return np.stack([cv2.projectPoints(cuboid, r, t, K, dist)[0].reshape(-1, 2) for r, t in poses])
    R = np.stack([cv2.Rodrigues(r)[0] for r, _ in poses])
    cam = cuboid @ R.transpose(0, 2, 1) + np.stack([t.reshape(3) for _, t in poses])[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(cam[..., 2:] > 0, (cam @ K.T)[..., :2] / cam[..., 2:], np.nan)


def _support(projected: np.ndarray, candidates: list[np.ndarray], centroid: np.ndarray,
             tau_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Of each pose's projected keypoints [H, K + 1, 2]: the summed belief of the candidates lying within ``tau_px``
    of their corner's projection (per corner the nearest), -1 where the centroid [2] does not project within
    ``tau_px``: scores [H]; and the candidate picked per corner, -1 where none: [H, K] int."""
    scores = np.zeros(len(projected))
    picks = np.full((len(projected), len(candidates)), -1)
    for k, found in enumerate(candidates):
        if len(found):
            d = np.linalg.norm(projected[:, k, None, :] - found[None, :, :2], axis=2)  # [H, C]; NaN: behind
            j = np.argmin(np.nan_to_num(d, nan=np.inf), axis=1)
            near = np.take_along_axis(d, j[:, None], axis=1)[:, 0] <= tau_px
            scores += np.where(near, found[j, 2], 0.0)
            picks[:, k] = np.where(near, j, -1)
    centred = np.linalg.norm(projected[:, -1] - centroid, axis=1) <= tau_px
    return np.where(centred, scores, -1.0), picks


def solve_pose_consensus(keypoints_2d: np.ndarray, candidates: list[np.ndarray], cuboid: np.ndarray, K: np.ndarray,
                         tau_px: float, dist: np.ndarray | None = None, seed: int = 0
                         ) -> tuple[np.ndarray, float, np.ndarray] | None:
    """``solve_pose`` of the keypoints that the best-supported hypothesis over the corners' candidate peaks picks
    (module docstring): (T_cam_obj [4, 4], mean reprojection error px, the keypoints picked [K + 1, 2]), or None
    where ``solve_pose`` of the keypoints as joined finds none.

    keypoints_2d [K + 1, 2] as ``solve_pose``'s (the corners as joined, then the centroid); candidates: per corner
    [C, 3] (x, y px, belief), ``decode.Detection.candidates`` in the same pixels; tau_px: how near a candidate must
    lie to a reprojected corner to support a pose (px)."""
    joined = solve_pose(keypoints_2d, cuboid, K, dist)
    if joined is None:
        return None
    if not any(len(found) > 1 or (len(found) == 1 and not np.allclose(found[0, :2], keypoints_2d[k]))
               for k, found in enumerate(candidates)):
        return (*joined, keypoints_2d)  # nothing to choose from
    K, cuboid, centroid = np.asarray(K, np.float64), np.asarray(cuboid, np.float64), keypoints_2d[-1]
    poses = [(cv2.Rodrigues(joined[0][:3, :3])[0], joined[0][:3, 3].reshape(3, 1))]
    drawable = np.array([k for k, found in enumerate(candidates) if len(found)])
    if len(drawable) >= SAMPLE:
        rng = np.random.default_rng(seed)
        corners = drawable[np.argsort(rng.random((HYPOTHESES, len(drawable))), axis=1)[:, :SAMPLE]]  # [H, SAMPLE]
        counts = np.array([len(c) for c in candidates])
        picks = (rng.random(corners.shape) * counts[corners]).astype(int)
        for ks, js in zip(corners, picks):
            image = np.array([*(candidates[k][j, :2] for k, j in zip(ks, js)), centroid])
            try:
                ok, rvec, tvec = cv2.solvePnP(cuboid[[*ks, -1]], image, K, dist, flags=cv2.SOLVEPNP_SQPNP)
            except cv2.error:
                continue
            if ok:
                poses.append((rvec, tvec))
    scores, picks = _support(_project(cuboid, poses, K, dist), candidates, centroid, tau_px)
    best = int(np.argmax(scores))  # the first of the best: the corners as joined on a tie
    if scores[best] < 0:
        return (*joined, keypoints_2d)
    keypoints = np.full_like(keypoints_2d, np.nan)
    keypoints[-1] = centroid
    for k, j in enumerate(picks[best]):
        if j >= 0:
            keypoints[k] = candidates[k][j, :2]
    solved = solve_pose(keypoints, cuboid, K, dist)
    return (*solved, keypoints) if solved is not None else (*joined, keypoints_2d)

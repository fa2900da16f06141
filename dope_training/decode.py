"""Object instances from DOPE's output maps (no network): belief peaks, sub-pixel keypoints, and corners
grouped to centroids by the affinity fields. After NVlabs/Deep_Object_Pose ``detector.py``, with this
stack's map convention.

Peaks: a copy of each belief map blurred with a Gaussian of ``blur_cells`` cells serves only to find them: a
peak is a cell of the blurred map >= its 4 neighbours (on a tie the right/lower cell wins, so a two-cell
plateau gives one peak) and > ``blur_threshold``; its score is the unblurred belief there, kept when >
min(``min_score``, ``CORNER_SCORE``) (a detection threshold above that must not take a detected instance's
corners away, nor its centroid the corners' grouping). Its sub-cell
position, along rows and along columns apart, is the vertex of the parabola through the logarithms of the
unblurred beliefs at the peak cell and its two neighbours (``subcell``: a Gaussian's logarithm is a parabola,
so this is exact for a Gaussian peak of any width, clamped to one cell; values floored at 1e-3), taken to
input pixels by ``targets.cells_to_pixels``, the exact inverse of how ``make_targets`` lays out the cells; so
there is no 0.4395 offset as upstream. On a map's border cell the missing neighbour leaves that coordinate at
the cell's centre (up to 4 px off).

Why not upstream's belief-weighted mean over a 5x5 window: it is off by up to 0.26 px on exact targets, a
same-kind keypoint 4 cells away pulls it by up to 7 px, and on a trained network's maps the low, noisy beliefs
around a peak pull it towards the window's centre. On the held-out set of ``docs/TRAINING.md`` (71 cups, with
``pnp``'s outlier dropping) the parabola lifted DOPE's ADD-S AUC from 0.671 to 0.746, from 0.611 to 0.695 and
from 0.509 to 0.602 for three networks.

Blur: 1 cell, where upstream uses 3. Our belief targets are 0.5 cell wide; measured on them, with 1 cell
both of two same-kind keypoints are found from 4 cells (32 px) apart, with 3 cells one of them is lost
in half the cases at 7 cells (56 px) and nearly always below.

Grouping: every centroid peak starts an instance. A corner peak of kind k may join an instance when the
unit vector from the corner to its centroid differs from the affinity of kind k read at the peak cell
(normalised) by a norm < ``max_angle_error`` (0.5: about 29 degrees). Of these pairs the nearest join
first, each peak and each instance's corner at most once. The direction alone cannot tell apart two
centroids in line with a corner (joining the best-aligned centroid went wrong in 4 % of 300 two-instance
scenes); the distance does, as upstream's choice of the nearest candidate.

Candidates: each instance also keeps, per corner kind, the peaks of that kind's map within ``CANDIDATE_REACH``
times its farthest joined corner's distance from its centroid, the joined one first, then the others by belief (at
most ``CANDIDATES``): where a look-alike part of the object (or another object) draws a corner's peak, the right
one is often a weaker peak nearby, which the grouping by distance passes over and ``pnp.solve_pose_consensus``
can pick up.

Corners: DOPE's 8 cuboid corners, or the K object points of a network with more maps (the centroid's map last);
the same rules for each.

Score: an instance's detection score is the geometric mean of its centroid's belief and the mean belief of its
corners (0 where not found), and instances under ``min_score`` are dropped once grouped. A look-alike in
real clutter (docs/TRAINING.md run GG) mostly has weaker corners around its centroid than an instance; on the generated
held-out frames of four LM-O objects the score separates the estimates on an instance from the others better
than the centroid's belief alone (ROC AUC 0.92-0.98 against 0.86-0.94). The geometric mean keeps a belief's
scale (a centroid and corners all at 0.6 score 0.6).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from dope_training.targets import cells_to_pixels

LOG_FLOOR = 1e-3  # beliefs below this count as this in the sub-cell fit
CORNER_SCORE = 0.1  # peaks (corners, and centroids before scoring) count above this belief (or min_score, if lower)
CANDIDATES = 3  # a corner's candidate peaks per instance, at most
CANDIDATE_REACH = 1.5  # candidates within this times the instance's farthest joined corner from its centroid


@dataclass
class Detection:
    """One instance: keypoints [K + 1, 2] in input pixels (corners 0..K-1, DOPE's 8 in its order, NaN where not
    found, then the centroid), scores [K + 1] (unblurred belief at each keypoint's peak, 0 where not found) and
    per corner its candidate peaks (module docstring), [C, 3] each (x, y input pixels, belief; C <= CANDIDATES,
    the joined corner first; none where the instance has no corner)."""

    keypoints: np.ndarray
    scores: np.ndarray
    candidates: list[np.ndarray] = field(default_factory=list)  # K of them once grouped

    @property
    def score(self) -> float:
        """The detection score: sqrt(centroid belief x mean corner belief), see the module docstring."""
        return float(np.sqrt(self.scores[-1] * self.scores[:-1].mean()))


def find_peaks(belief: np.ndarray, stride: int = 8, blur_cells: float = 1.0, blur_threshold: float = 0.01,
               min_score: float = 0.1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Peaks of one belief map [h, w] (see the module docstring): points [P, 2] (x, y input pixels),
    cells [P, 2] (row, column of the peak cell) and scores [P]."""
    belief = np.asarray(belief, dtype=np.float32)
    blurred = cv2.GaussianBlur(belief, (0, 0), blur_cells, borderType=cv2.BORDER_REFLECT)
    padded = np.pad(blurred, 1, constant_values=-np.inf)
    centre = padded[1:-1, 1:-1]
    is_peak = ((centre >= padded[1:-1, :-2]) & (centre > padded[1:-1, 2:]) & (centre >= padded[:-2, 1:-1])
               & (centre > padded[2:, 1:-1]) & (centre > blur_threshold) & (belief > min_score))
    cells = np.argwhere(is_peak)
    points = np.array([subcell(belief, i, j)[::-1] for i, j in cells]).reshape(-1, 2)
    return cells_to_pixels(points, stride), cells, belief[tuple(cells.T)]


def subcell(belief: np.ndarray, i: int, j: int) -> np.ndarray:
    """(row, column) [2] in fractional cells of the peak at cell (i, j) of ``belief`` [h, w]: per axis the vertex
    of the parabola through log(belief) at the cell and its two neighbours, within a cell of it (the peak of
    the blurred map can be the cell next to the unblurred one's)."""
    position = np.array([i, j], dtype=np.float64)

    def log(cell: tuple[int, int]) -> float:
        return float(np.log(max(float(belief[cell]), LOG_FLOOR)))

    for axis, (before, after) in enumerate((((i - 1, j), (i + 1, j)), ((i, j - 1), (i, j + 1)))):
        if min(before) < 0 or after[0] >= belief.shape[0] or after[1] >= belief.shape[1]:
            continue  # border cell: no neighbour on one side
        left, centre, right = log(before), log((i, j)), log(after)
        curvature = left - 2 * centre + right
        if curvature < 0:
            position[axis] += np.clip(0.5 * (left - right) / curvature, -1.0, 1.0)
    return position


def find_keypoints(beliefs: np.ndarray, affinities: np.ndarray, stride: int = 8, blur_cells: float = 1.0,
                   blur_threshold: float = 0.01, min_score: float = 0.1,
                   max_angle_error: float = 0.5) -> list[Detection]:
    """Instances in one image's maps: beliefs [K + 1, h, w], affinities [2 K, h, w] (the network's last stage).

    Returns Detections (keypoints in input pixels of the network's input) scoring above ``min_score``, highest
    score first.
    """
    peak_score = min(min_score, CORNER_SCORE)
    corners = len(beliefs) - 1
    centroids, _, centroid_scores = find_peaks(beliefs[-1], stride, blur_cells, blur_threshold, peak_score)
    order = np.argsort(-centroid_scores, kind="stable")
    centroids, centroid_scores = centroids[order], centroid_scores[order]
    detections = []
    for centroid, score in zip(centroids, centroid_scores):
        keypoints = np.full((corners + 1, 2), np.nan)
        keypoints[-1] = centroid
        detections.append(Detection(keypoints, np.r_[np.zeros(corners), score]))
    peaks = [find_peaks(beliefs[k], stride, blur_cells, blur_threshold, peak_score) for k in range(corners)]
    for k, (points, cells, scores) in enumerate(peaks):
        pairs = []  # (distance, peak, instance) of every pair whose directions agree
        for p, (point, (i, j)) in enumerate(zip(points, cells)):
            affinity = affinities[2 * k:2 * k + 2, i, j].astype(np.float64)
            if np.linalg.norm(affinity) < 1e-6:
                continue
            to_centroid = centroids - point
            distances = np.linalg.norm(to_centroid, axis=1)
            errors = np.linalg.norm(to_centroid / np.maximum(distances, 1e-9)[:, None]
                                    - affinity / np.linalg.norm(affinity), axis=1)
            pairs += [(distances[n], p, n) for n in np.flatnonzero(errors < max_angle_error)]
        used = set()
        for _, p, n in sorted(pairs):
            if p not in used and np.isnan(detections[n].keypoints[k, 0]):
                used.add(p)
                detections[n].keypoints[k] = points[p]
                detections[n].scores[k] = scores[p]
    kept = [d for d in detections if d.score > min_score]
    kinds = [(points, scores) for points, _, scores in peaks]
    for d in kept:
        d.candidates = corner_candidates(d.keypoints, kinds)
    return sorted(kept, key=lambda d: -d.score)


def corner_candidates(keypoints: np.ndarray, peaks: list[tuple[np.ndarray, np.ndarray]]) -> list[np.ndarray]:
    """Per corner kind, [C, 3] (x, y, belief) candidate peaks of the instance whose keypoints [K + 1, 2] are given
    (module docstring), from each kind's peaks: (points [P, 2], beliefs [P])."""
    distances = np.linalg.norm(keypoints[:-1] - keypoints[-1], axis=1)
    if np.isnan(distances).all():
        return [np.zeros((0, 3))] * len(peaks)
    reach = CANDIDATE_REACH * np.nanmax(distances)
    out = []
    for k, (points, scores) in enumerate(peaks):
        near = np.linalg.norm(points - keypoints[-1], axis=1) < reach  # points [P, 2], P may be 0
        joined = np.all(points == keypoints[k], axis=1)  # none where the corner was not joined (NaN)
        # the joined corner first, then the others by belief (np.lexsort: the last key is the primary one)
        order = np.lexsort((-scores, ~joined))
        order = order[near[order]][:CANDIDATES]
        out.append(np.column_stack([points[order], scores[order]]).reshape(-1, 3))
    return out

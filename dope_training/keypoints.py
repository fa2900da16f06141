"""The object points whose projections DOPE's network learns to find, and PnP solves the pose from.

``cuboid`` (DOPE's): the 8 corners of the model's bounding box (DOPE's order) and its centre. ``surface``: K
(8 unless asked) points on the model's surface chosen by farthest-point sampling from the box's centre (as
PVNet chooses its keypoints), and the box's centre: points on the object, where the pixels show them, instead of
corners in the air around it that the network must infer from the object's whole shape. The centre stays the
box's either way (the distance head and the grouping read it). A checkpoint carries its points
(``TargetObject.keypoints``; none: the cuboid), so inference solves PnP with the points the network learnt.
"""

from __future__ import annotations

import numpy as np
import trimesh

from pegasus_gen.geometry.cuboid import cuboid_points

SURFACE_CANDIDATES = 5000  # area-uniform samples of the model's surface the farthest points are chosen from


def farthest_points(points: np.ndarray, start: np.ndarray, count: int) -> np.ndarray:
    """``count`` rows of ``points`` [N, 3], each the one farthest from ``start`` [3] and the rows chosen
    before it (greedy farthest-point sampling; ties to the lowest index) -> [count, 3]."""
    points = np.asarray(points, np.float64)
    nearest = np.linalg.norm(points - np.asarray(start, np.float64), axis=1)
    chosen = []
    for _ in range(count):
        i = int(np.argmax(nearest))
        chosen.append(i)
        nearest = np.minimum(nearest, np.linalg.norm(points - points[i], axis=1))
    return points[chosen]


def surface_keypoints(mesh: trimesh.Trimesh, bbox_min, bbox_size, count: int = 8) -> np.ndarray:
    """[count + 1, 3] (the mesh's units, model frame): ``count`` farthest points of ``SURFACE_CANDIDATES``
    samples of the mesh's surface (the same for every run), from the centre of the box (``bbox_min``,
    ``bbox_size`` [3]), then that centre. The first 8 of 12 are the 8 of 8: more points add to DOPE's."""
    centre = cuboid_points(bbox_min, bbox_size)[8]
    points, _ = trimesh.sample.sample_surface(mesh, SURFACE_CANDIDATES, seed=0)
    return np.vstack([farthest_points(points, centre, count), centre])


def object_keypoints(keypoints, bbox_min, bbox_size) -> np.ndarray:
    """[P, 3] float64: ``keypoints`` (a TargetObject's, [P, 3], the centre last) or, where None, the box's cuboid
    (``cuboid_points``, [9, 3])."""
    if keypoints is None:
        return cuboid_points(bbox_min, bbox_size)
    return np.asarray(keypoints, np.float64)

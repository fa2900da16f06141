"""Refine a DOPE pose of a rigid object against a depth image: re-anchor along the viewing ray, then
point-to-plane ICP of the object's model points to the observed depth, with a gate that rejects poses the
depth does not confirm.

Re-anchoring: DOPE usually finds the object's 2D centre but often gets its distance wrong (the
translation scaled by 1.3-1.5 along the ray), too far for ICP to recover. So the object first slides along
the ray through its centre until the model's visible surface, at the ``anchor_percentile`` of its depth
over the central part of its projected box, has the depth observed there (twice, the second time with the
box of the moved object). The scene cloud is the depth back-projected inside the projected box (plus a
margin) and kept within a sphere of the model's radius plus ``search_margin_m`` around the object's
centre, so the table and neighbouring objects cannot capture the model.

ICP: open3d point-to-plane ICP (normals of the scene cloud from its neighbours, oriented to the camera)
over a coarse-to-fine schedule of correspondence distances. The source is the model points that face the
camera at the current pose (normal within ``max_facing_deg`` of the direction to the camera) and project
into the image, chosen again before each stage; it is not a z-buffer, so a concave object's self-occluded
points facing the camera count as visible. An object with a continuous rotation symmetry (``symmetry_axis``)
keeps the input's angle about that axis: after each stage its rotation is replaced by the input rotation
turned by the smallest rotation that takes the input's axis to the refined axis, so only the axis' tilt
and the translation are refined and the result does not spin.

Gate: accepted only if the crop held at least ``min_depth_points`` depth points, at most ``max_occluded`` of
the visible model points are hidden behind nearer depth (another object, a shelf's edge), the fitness (over
the rest) is at least ``min_fitness``, the RMSE of its correspondences at most ``max_rmse_m``, and the object
moved by at most ``max_move_fraction`` of its initial distance from the camera and turned by at most
``max_rotation_deg``; otherwise the input pose comes back with ``accepted=False`` and a one-line reason.
Fitness is the fraction of the visible, unoccluded model points within the last correspondence distance of
the depth pixel each projects to, measured along the point's normal (``depth_support``). Pairing along the
ray (not with the nearest scene point in 3D) counts a point hidden behind the observed surface as
unsupported: with the object absent, ICP sinks the model into the table until one face lies in its plane,
and a 3D nearest neighbour would support its hidden sides (and these, hidden by the table, count as
occluded only if the supporting depth is not one plane).
Only malformed inputs raise (``PegasusError``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
import open3d as o3d

from pegasus_gen.errors import PegasusError
from pegasus_gen.geometry.pose_error import adds_error


@dataclass
class Refinement:
    """T [4, 4] refined T_cam_obj (metres, OpenCV camera frame; the input pose when rejected), accepted,
    fitness (fraction of the visible, unoccluded model points with a depth point within the final correspondence
    distance: the depth pixel each projects to, distance along the point's normal; see ``depth_support``),
    rmse_m (metres, of those correspondences), reason ('' when accepted, else one short line), occluded
    (fraction of the visible model points hidden behind nearer depth)."""

    T: np.ndarray
    accepted: bool
    fitness: float
    rmse_m: float
    reason: str
    occluded: float = 0.0

    @property
    def support(self) -> float:
        """The fraction of all the visible model points the depth confirms: fitness x (1 - occluded)."""
        return self.fitness * (1.0 - self.occluded)


@dataclass
class RefineParams:
    """The knobs of ``refine_pose``."""

    median_px: int = 3  # side of the median filter on the depth that removes speckle (3 or 5; 0 = none), pixels
    box_margin_px: int = 8  # pixels added on each side of the projected model box for the depth crop
    anchor_core: float = 0.5  # side of the box's central part whose depth re-anchors the pose, fraction of the box
    anchor_percentile: float = 50.0  # percentile of depth compared there (observed and model alike), 0-100
    search_margin_m: float = 0.02  # metres added to the model radius for the sphere the scene points are kept in
    normal_radius_m: float = 0.008  # metres, neighbourhood for the scene normals (at most 30 neighbours)
    max_facing_deg: float = 85.0  # degrees between a model normal and the direction to the camera, to be visible
    distances_m: tuple[float, ...] = (0.03, 0.015, 0.008, 0.004)  # ICP correspondence distance per stage, metres
    iterations: int = 30  # ICP iterations per stage at most
    min_depth_points: int = 100  # depth points needed in the crop
    min_fitness: float = 0.8  # fraction of the visible, unoccluded model points with depth within distances_m[-1]
    max_occluded: float = 0.5  # fraction of the visible model points that nearer depth may hide
    max_rmse_m: float = 0.003  # metres, RMSE of those correspondences
    max_move_fraction: float = 0.5  # the object's centre may move by this fraction of its initial distance
    max_rotation_deg: float = 45.0  # degrees the refined rotation may differ from the input's
    confident_fitness: float = 0.95  # refine_multistart tries other starts unless the first's support reaches this
    # ... and keeps an accepted first start when the best other one lies within same_surface_m ADD-S of it (m)
    # and gains less than same_surface_gain support: the depth cannot tell such poses apart (a textured cup
    # turned about its axis gained 0.06), the network's rotation can; a cup upside down gained 0.17
    same_surface_m: float = 0.01
    same_surface_gain: float = 0.1


def refine_pose(T_cam_obj: np.ndarray, depth_m: np.ndarray, K: np.ndarray, model_points: np.ndarray,
                model_normals: np.ndarray | None = None, symmetry_axis: np.ndarray | None = None,
                params: RefineParams | None = None) -> Refinement:
    """Refine T_cam_obj [4, 4] (metres) of an object against depth_m [H, W] (z-depth, metres; 0 or NaN = no
    depth) seen with K [3, 3] (pixels). model_points [N, 3] metres, surface samples in the object frame;
    model_normals [N, 3] their outward unit normals (estimated from the points when None); symmetry_axis [3]
    (object frame, through its origin) for an object with continuous rotation symmetry, else None.
    Raises PegasusError only for malformed inputs; a pose the depth does not confirm comes back rejected.
    """
    T_in, depth, K, points, normals, axis = _checked(T_cam_obj, depth_m, K, model_points, model_normals,
                                                     symmetry_axis)
    p = params or RefineParams()
    if p.median_px not in (0, 1, 3, 5) or not p.distances_m:
        raise PegasusError(f"refine_pose: median_px must be 0, 1, 3 or 5 and distances_m not empty, got {p}")
    if p.median_px > 1:
        depth = cv2.medianBlur(depth, p.median_px)
    if normals is None:
        normals = estimate_normals(points)
    centre = (points.min(0) + points.max(0)) / 2
    radius = float(np.linalg.norm(points - centre, axis=1).max())

    def reject(reason: str, fitness: float = 0.0, rmse: float = 0.0, occluded: float = 0.0) -> Refinement:
        return Refinement(T_in.copy(), False, fitness, rmse, reason, occluded)

    if (T_in[:3, :3] @ centre + T_in[:3, 3])[2] <= radius:
        return reject("the pose puts the object behind or against the camera")
    T = T_in
    for _ in range(2):
        T, problem = reanchor(T, depth, K, points, normals, p)
        if problem:
            return reject(problem)
    scene = scene_cloud(T, depth, K, points, centre, radius, p)
    if len(scene.points) < p.min_depth_points:
        return reject(f"{len(scene.points)} depth points near the object < {p.min_depth_points}")
    T = icp(T, scene, points, normals, K, depth.shape, axis, T_in[:3, :3], p)
    if not np.isfinite(T).all():
        return reject("ICP diverged")
    seen = visible(T, points, normals, K, depth.shape, p.max_facing_deg)
    fitness, rmse, occluded = depth_support(T, points[seen], normals[seen], depth, K, p.distances_m[-1])
    moved = float(np.linalg.norm((T[:3, :3] - T_in[:3, :3]) @ centre + T[:3, 3] - T_in[:3, 3]))
    start = float(np.linalg.norm(T_in[:3, :3] @ centre + T_in[:3, 3]))
    turned = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3].T @ T_in[:3, :3]) - 1) / 2, -1.0, 1.0)))
    if occluded > p.max_occluded:
        return reject(f"{100 * occluded:.0f} % of the object hidden by nearer depth > {100 * p.max_occluded:.0f} %",
                      fitness, rmse, occluded)
    if fitness < p.min_fitness:
        return reject(f"fitness {fitness:.2f} < {p.min_fitness}", fitness, rmse, occluded)
    if rmse > p.max_rmse_m:
        return reject(f"rmse {rmse * 1e3:.1f} mm > {p.max_rmse_m * 1e3:.1f} mm", fitness, rmse, occluded)
    if moved > p.max_move_fraction * start:
        return reject(f"moved {moved:.3f} m > {p.max_move_fraction} x {start:.3f} m", fitness, rmse, occluded)
    if turned > p.max_rotation_deg:
        return reject(f"turned {turned:.0f} deg > {p.max_rotation_deg:.0f} deg", fitness, rmse, occluded)
    return Refinement(T, True, fitness, rmse, "", occluded)


def icp(T: np.ndarray, scene: o3d.geometry.PointCloud, points: np.ndarray, normals: np.ndarray, K: np.ndarray,
        shape: tuple[int, int], axis: np.ndarray | None, R_in: np.ndarray, p: RefineParams) -> np.ndarray:
    """T_cam_obj [4, 4] registered by point-to-plane ICP, stage by stage over ``p.distances_m``, of the model
    points (object frame, [N, 3] metres, outward normals [N, 3]) that are visible at the current pose to
    ``scene`` (camera frame, metres). The work is done in a frame shifted to the object's centre, so that
    the update's rotation and translation are decoupled (a turn about the object's own axis is then a pure
    rotation). With a symmetry ``axis`` [3] the angle about it is reset to R_in's [3, 3] after each stage."""
    reg = o3d.pipelines.registration
    shift = np.eye(4)
    shift[:3, 3] = -(T[:3, :3] @ ((points.min(0) + points.max(0)) / 2) + T[:3, 3])
    target = o3d.geometry.PointCloud(scene).translate(shift[:3, 3])
    target.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=p.normal_radius_m, max_nn=30))
    target.orient_normals_towards_camera_location(shift[:3, 3])
    for distance in p.distances_m:
        seen = visible(T, points, normals, K, shape, p.max_facing_deg)
        if seen.sum() < 10:
            break
        result = reg.registration_icp(_cloud(points[seen]), target, distance, shift @ T,
                                      reg.TransformationEstimationPointToPlane(),
                                      reg.ICPConvergenceCriteria(max_iteration=p.iterations))
        T = np.linalg.inv(shift) @ np.asarray(result.transformation)
        if axis is not None:
            T[:3, :3] = keep_spin(T[:3, :3], R_in, axis)
    return T


def reanchor(T: np.ndarray, depth: np.ndarray, K: np.ndarray, points: np.ndarray, normals: np.ndarray,
             p: RefineParams) -> tuple[np.ndarray, str]:
    """(T_cam_obj [4, 4] moved along the ray through the object's centre so that the depth of its visible
    model points matches the observed depth over the central part of its projected box, problem): problem is
    '' or one line saying why it cannot be done (then T is the input). depth [H, W] metres (0 = none), K [3, 3],
    points, normals [N, 3] object frame."""
    box = _projected_box(T, points, K, depth.shape, 0)
    if box is None:
        return T, "the object projects outside the image"
    u0, v0, u1, v1 = box
    du, dv = (1 - p.anchor_core) / 2 * (u1 - u0), (1 - p.anchor_core) / 2 * (v1 - v0)
    cu0, cv0, cu1, cv1 = int(np.floor(u0 + du)), int(np.floor(v0 + dv)), int(np.ceil(u1 - du)), int(np.ceil(v1 - dv))
    core = depth[cv0:cv1 + 1, cu0:cu1 + 1]
    observed = core[core > 0]
    if len(observed) < 10:
        return T, "no depth inside the object's projected box"
    cam = points[visible(T, points, normals, K, depth.shape, 90.0)] @ T[:3, :3].T + T[:3, 3]
    u, v = _project(cam, K)
    inside = (u >= cu0) & (u <= cu1) & (v >= cv0) & (v <= cv1)
    model_z = cam[inside, 2] if inside.sum() >= 10 else cam[:, 2]
    shift = float(np.percentile(observed, p.anchor_percentile) - np.percentile(model_z, p.anchor_percentile))
    centre = T[:3, :3] @ ((points.min(0) + points.max(0)) / 2) + T[:3, 3]
    if centre[2] + shift <= 0.5 * centre[2]:
        return T, f"the depth in the object's box is {-shift:.3f} m nearer than the object (occluded?)"
    out = T.copy()
    out[:3, 3] += centre * shift / centre[2]  # every point's z changes by ``shift``, the projected centre stays
    return out, ""


def scene_cloud(T: np.ndarray, depth: np.ndarray, K: np.ndarray, points: np.ndarray, centre: np.ndarray,
                radius: float, p: RefineParams) -> o3d.geometry.PointCloud:
    """The observed depth back-projected (camera frame, metres) inside the model's projected box at T [4, 4]
    plus ``box_margin_px``, kept within ``radius + search_margin_m`` (metres) of the model's centre [3]
    (object frame). depth [H, W] metres (0 = none), K [3, 3], points [N, 3] object frame."""
    box = _projected_box(T, points, K, depth.shape, p.box_margin_px)
    if box is None:
        return o3d.geometry.PointCloud()
    u0, v0, u1, v1 = (int(round(x)) for x in box)
    z = depth[v0:v1 + 1, u0:u1 + 1]
    v, u = np.nonzero(z > 0)
    z = z[v, u]
    xyz = np.stack([(u + u0 - K[0, 2]) * z / K[0, 0], (v + v0 - K[1, 2]) * z / K[1, 1], z], axis=1)
    near = np.linalg.norm(xyz - (T[:3, :3] @ centre + T[:3, 3]), axis=1) <= radius + p.search_margin_m
    return _cloud(xyz[near])


def visible(T: np.ndarray, points: np.ndarray, normals: np.ndarray, K: np.ndarray, shape: tuple[int, int],
            max_facing_deg: float) -> np.ndarray:
    """[N] bool: model points (object frame, [N, 3] metres, outward normals [N, 3]) that at T_cam_obj [4, 4]
    project into the image of ``shape`` (H, W) and whose normal is within ``max_facing_deg`` of the direction
    to the camera. No z-buffer: self-occlusion of concave objects is not considered."""
    cam = points @ T[:3, :3].T + T[:3, 3]
    n = normals @ T[:3, :3].T
    facing = -np.einsum("ij,ij->i", n, cam) > np.cos(np.radians(max_facing_deg)) * np.linalg.norm(cam, axis=1)
    u, v = _project(cam, K)
    return facing & (cam[:, 2] > 0) & (u >= -0.5) & (u <= shape[1] - 0.5) & (v >= -0.5) & (v <= shape[0] - 0.5)


def depth_support(T: np.ndarray, points: np.ndarray, normals: np.ndarray, depth: np.ndarray, K: np.ndarray,
                  distance: float) -> tuple[float, float, float]:
    """(fitness, rmse metres, occluded fraction) of model points [N, 3] with outward normals [N, 3] (object
    frame, metres) at T_cam_obj [4, 4] against depth [H, W] (metres, 0 = none). Each point is paired with the
    depth pixel it projects to and their distance is measured along the point's normal (point to plane). A
    point not within ``distance`` (metres) whose depth pixel lies nearer than it by more than ``distance`` is
    occluded: something in front hides it, so it neither supports nor contradicts the pose; unless the depth
    points that support the pose lie in one plane (their spread off it under ``distance``), then no point is:
    a plane cannot tell the object from a surface it would be sunk in (a box pushed into the table until
    one face is in the table's plane has its other faces "occluded" by the table). Fitness is the fraction of the
    points not occluded that lie within ``distance``, rmse the RMS distance of those. Pairing along the
    point's own ray, a point hidden behind the observed surface finds no support, where its nearest
    neighbour in 3D could lie on that surface."""
    if len(points) == 0:
        return 0.0, 0.0, 1.0
    cam = points @ T[:3, :3].T + T[:3, 3]
    u, v = _project(cam, K)
    ui = np.clip(np.round(u).astype(int), 0, depth.shape[1] - 1)
    vi = np.clip(np.round(v).astype(int), 0, depth.shape[0] - 1)
    z = depth[vi, ui]
    xyz = np.stack([(ui - K[0, 2]) * z / K[0, 0], (vi - K[1, 2]) * z / K[1, 1], z], axis=1)
    gap = np.where(z > 0, np.abs(np.einsum("ij,ij->i", xyz - cam, normals @ T[:3, :3].T)), np.inf)
    inliers = gap <= distance
    occluded = ~inliers & (z > 0) & (z < cam[:, 2] - distance)
    if not _off_one_plane(xyz[inliers], distance):
        occluded[:] = False
    if occluded.all():
        return 0.0, 0.0, 1.0
    rmse = float(np.sqrt(np.mean(gap[inliers] ** 2))) if inliers.any() else 0.0
    return float(inliers.sum() / (~occluded).sum()), rmse, float(occluded.mean())


def _off_one_plane(points: np.ndarray, min_std_m: float) -> bool:
    """Whether points [N, 3] (metres) stand out of their best-fitting plane: their spread along its normal
    (the smallest principal standard deviation) is at least ``min_std_m``."""
    if len(points) < 3:
        return False
    return bool(np.sqrt(max(np.linalg.eigvalsh(np.cov(points.T))[0], 0.0)) >= min_std_m)


def turn(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """[3, 3]: the smallest rotation that takes the unit vector ``a`` [3] to the unit vector ``b`` [3] (a half
    turn about some axis perpendicular to ``a`` when they are opposite)."""
    c = float(np.clip(a @ b, -1.0, 1.0))
    w = np.cross(a, b)
    if np.linalg.norm(w) < 1e-12:
        if c > 0:
            return np.eye(3)
        w = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    w = w / np.linalg.norm(w)
    W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    s = np.sqrt(max(0.0, 1 - c * c))
    return np.eye(3) + s * W + (1 - c) * W @ W


def keep_spin(R: np.ndarray, R_in: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """R_in [3, 3] turned by the smallest rotation that takes its symmetry axis (R_in @ axis) to R @ axis:
    R's tilt of the axis with R_in's angle about it. axis [3] unit, object frame."""
    return turn(R_in @ axis, R @ axis) @ R_in


# 14 directions (the cube's 6 face normals and 8 corners) and the cube's 24 rotations: the other starts of
# ``refine_multistart``; any direction is within 37 degrees of one of the 14.
START_DIRECTIONS = np.concatenate([np.concatenate([np.eye(3), -np.eye(3)]),
                                   np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T / np.sqrt(3)])
CUBE_ROTATIONS = [np.eye(3)[list(order)] * np.array(signs)[:, None]
                  for order in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0))
                  for signs in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
                  if np.linalg.det(np.eye(3)[list(order)] * np.array(signs)[:, None]) > 0]


def refine_multistart(T_cam_obj: np.ndarray, depth_m: np.ndarray, K: np.ndarray, model_points: np.ndarray,
                      model_normals: np.ndarray | None = None, symmetry_axis: np.ndarray | None = None,
                      params: RefineParams | None = None) -> Refinement:
    """``refine_pose`` from T_cam_obj [4, 4] and, unless that is accepted with a support
    (``Refinement.support``) of at least ``params.confident_fitness``, from the same position with other
    rotations: for a symmetric object the axis turned to each of the 14 ``START_DIRECTIONS`` (camera frame),
    otherwise the rotation composed with each of the cube's 23 other rotations. A wrong rotation from PnP
    (wrong corners) is beyond ICP's reach (and a cup upside down still fits its depth at a fitness of 0.83);
    the position from the centroid and the depth is not. These starts are a grid, not estimates (the cube's
    rotations lie up to 63 degrees from the truth), so from them ICP may turn any amount. Returns the
    accepted refinement of highest support (a pose with much of the object hidden explains less than one
    without), or the first start's rejection. An accepted first start stands against a best within
    ``params.same_surface_m`` ADD-S of it that gains less than ``params.same_surface_gain`` support.
    Arguments as ``refine_pose``."""
    p = params or RefineParams()
    first = refine_pose(T_cam_obj, depth_m, K, model_points, model_normals, symmetry_axis, p)
    if first.accepted and first.support >= p.confident_fitness:
        return first
    R = T_cam_obj[:3, :3]
    if symmetry_axis is not None:
        axis = np.asarray(symmetry_axis, np.float64) / np.linalg.norm(symmetry_axis)
        rotations = [turn(R @ axis, d) @ R for d in START_DIRECTIONS]
    else:
        rotations = [R @ G for G in CUBE_ROTATIONS if not np.allclose(G, np.eye(3))]
    middle = (model_points.min(0) + model_points.max(0)) / 2  # turned about the object's middle
    free = replace(p, max_rotation_deg=180.0)  # these starts are a grid, not an estimate to stay near
    best = first
    for rotation in rotations:
        start = T_cam_obj.copy()
        start[:3, :3] = rotation
        start[:3, 3] = R @ middle + T_cam_obj[:3, 3] - rotation @ middle
        result = refine_pose(start, depth_m, K, model_points, model_normals, symmetry_axis, free)
        if result.accepted and (not best.accepted or result.support > best.support):
            best = result
    if (first.accepted and best.support - first.support < p.same_surface_gain
            and adds_error(model_points, best.T, first.T) <= p.same_surface_m):
        return first
    return best


def estimate_normals(points: np.ndarray) -> np.ndarray:
    """Unit normals [N, 3] of surface samples points [N, 3] (metres) from their 20 nearest neighbours,
    turned away from the points' bounding-box centre (right for convex objects)."""
    cloud = _cloud(points)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=20))
    n = np.asarray(cloud.normals)
    outward = np.einsum("ij,ij->i", n, points - (points.min(0) + points.max(0)) / 2) >= 0
    return np.where(outward[:, None], n, -n)


def _projected_box(T, points, K, shape, margin_px) -> tuple[float, float, float, float] | None:
    """(u0, v0, u1, v1) pixels: the box of the model points [N, 3] projected at T [4, 4] (those in front of
    the camera) grown by margin_px and clipped to the image of ``shape`` (H, W); None when it misses it."""
    cam = points @ T[:3, :3].T + T[:3, 3]
    cam = cam[cam[:, 2] > 1e-3]
    if len(cam) == 0:
        return None
    u, v = _project(cam, K)
    u0, u1 = max(u.min() - margin_px, 0.0), min(u.max() + margin_px, shape[1] - 1.0)
    v0, v1 = max(v.min() - margin_px, 0.0), min(v.max() + margin_px, shape[0] - 1.0)
    return (u0, v0, u1, v1) if u0 <= u1 and v0 <= v1 else None


def _project(cam: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (u [N], v [N]) of camera-frame points cam [N, 3] (z > 0)."""
    z = np.maximum(cam[:, 2], 1e-9)
    return K[0, 0] * cam[:, 0] / z + K[0, 2], K[1, 1] * cam[:, 1] / z + K[1, 2]


def _cloud(xyz: np.ndarray) -> o3d.geometry.PointCloud:
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(xyz, dtype=np.float64)))


def _checked(T, depth, K, points, normals, axis):
    """The inputs as float64 arrays (depth float32, 0 where none); PegasusError naming the first malformed one."""
    try:
        T, depth, K, points = (np.asarray(x, dtype=np.float64) for x in (T, depth, K, points))
    except (TypeError, ValueError) as exc:
        raise PegasusError(f"refine_pose: inputs must be numeric arrays ({exc})") from None
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise PegasusError(f"refine_pose: T_cam_obj must be a finite 4x4 matrix, got shape {T.shape}")
    if not np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-4) or np.linalg.det(T[:3, :3]) < 0:
        raise PegasusError("refine_pose: T_cam_obj must be a rigid transform (orthonormal rotation, det +1)")
    if depth.ndim != 2:
        raise PegasusError(f"refine_pose: depth_m must be an H x W image in metres, got shape {depth.shape}")
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise PegasusError(f"refine_pose: K must be a finite 3x3 intrinsic matrix with fx, fy > 0, got shape {K.shape}")
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < 10 or not np.isfinite(points).all():
        raise PegasusError(f"refine_pose: model_points must be N x 3 (N >= 10) finite metres, got shape {points.shape}")
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != points.shape or not np.isfinite(normals).all():
            raise PegasusError(f"refine_pose: model_normals must be {points.shape[0]} x 3 like model_points, "
                               f"got shape {normals.shape}")
        normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    if axis is not None:
        axis = np.asarray(axis, dtype=np.float64)
        if axis.shape != (3,) or not np.isfinite(axis).all() or np.linalg.norm(axis) < 1e-9:
            raise PegasusError(f"refine_pose: symmetry_axis must be a non-zero 3-vector, got {axis.tolist()}")
        axis = axis / np.linalg.norm(axis)
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
    return T, depth, K, points, normals, axis

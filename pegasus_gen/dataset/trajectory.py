"""A scene's camera trajectory (``camera_trajectory``): key poses around its objects that see them unblocked by the
environment with the environment filling the view, in a share of the scenes chosen to show the labelled objects
partly hidden by the others (``Hiding``), interpolated into frames."""

from __future__ import annotations

import numpy as np
import trimesh

from pegasus_gen.dataset.config import GenerateConfig
from pegasus_gen.geometry.cameras import interpolate_poses, orbit_key_poses
from pegasus_gen.render.raycast import MeshRaycaster, SceneRaycaster

BLOCKING_MARGIN = 0.03  # m: the environment may come this close in front of an object's centre (its support)
HIDDEN_WANTED = 0.5  # the share of a labelled object's side facing the camera that occluding key poses seek hidden
HIDING_POINTS = 48  # points on each labelled object's surface that the share is measured at
HIDING_MARGIN = 0.005  # m: a hit this close before a point is the point's own surface


class Hiding:
    """How much of each labelled instance of a scene the other placed objects and distractors hide from an eye:
    ``HIDING_POINTS`` points on its surface (world frame, m) with their normals, and every placed object's
    collision mesh in the world for ray casting."""

    def __init__(self, objects: list, poses: dict[int, np.ndarray], targets: int, rng: np.random.Generator):
        """``objects``: a scene's assets and distractors by instance index (the first ``targets`` labelled), each
        with its collision ``mesh`` and ``surface`` (trimesh, its own frame, m); ``poses``: T_world_obj [4, 4] of
        those kept, by index; ``rng`` draws the points."""
        kept = sorted(poses)
        self.raycaster = SceneRaycaster([objects[i].mesh.copy().apply_transform(poses[i]) for i in kept])
        self.points, self.normals, self.mesh_index = [], [], []
        for k, i in enumerate(kept):
            if i >= targets:
                continue
            surface = objects[i].surface if objects[i].surface is not None else objects[i].mesh
            points, faces = trimesh.sample.sample_surface(surface, HIDING_POINTS, seed=int(rng.integers(2**31)))
            self.points.append(points @ poses[i][:3, :3].T + poses[i][:3, 3])
            self.normals.append(surface.face_normals[faces] @ poses[i][:3, :3].T)
            self.mesh_index.append(k)

    def hidden(self, eye: np.ndarray) -> np.ndarray:
        """[targets] the share of each labelled instance's points facing ``eye`` [3] (world, m) whose ray from the
        eye first hits another placed object before the point (0 where none of its points faces the eye)."""
        out = np.zeros(len(self.points))
        for n, (points, normals, k) in enumerate(zip(self.points, self.normals, self.mesh_index)):
            towards = eye - points
            facing = (normals * towards).sum(axis=1) > 0
            if not facing.any():
                continue
            distance = np.linalg.norm(towards[facing], axis=1)
            t, index = self.raycaster.first_hit(eye, -towards[facing] / distance[:, None])
            out[n] = np.mean((index >= 0) & (index != k) & (t < distance - HIDING_MARGIN))
        return out


def hiding_score(hidden: np.ndarray) -> float:
    """0..1: how near the shares ``hidden`` [targets] lie to ``HIDDEN_WANTED`` on average (1 there, 0 at none
    or all hidden)."""
    if not len(hidden):
        return 0.0
    return float(np.mean(np.minimum(hidden / HIDDEN_WANTED, (1.0 - hidden) / (1.0 - HIDDEN_WANTED))))


def camera_trajectory(environment: trimesh.Trimesh, objects: list, poses: dict[int, np.ndarray], targets: int,
                      cfg: GenerateConfig, K: np.ndarray, keys_rng: np.random.Generator,
                      rng: np.random.Generator) -> list[np.ndarray]:
    """T_cam_world per frame of a scene (``environment``'s collision mesh in the world; ``objects``, ``poses`` and
    ``targets`` as ``Hiding`` takes them): key poses around the objects' centre, drawn from ``keys_rng``,
    interpolated. Key poses must see every object's centre unblocked by the environment, and are redrawn until the
    environment fills at least ``trajectory.min_view_coverage`` of the image (else the best draw is kept). In
    ``trajectory.occlusion`` of the scenes (drawn from ``rng``, as the points ``Hiding`` measures at) every try, its
    azimuth redrawn too, is scored, and the draw kept that also has the labelled objects nearest to half hidden by
    the other objects (``Hiding``, ``hiding_score``)."""
    t = cfg.trajectory
    centres = np.array([pose[:3, 3] for pose in poses.values()])
    W, H = cfg.camera.width, cfg.camera.height
    caster = MeshRaycaster(environment)
    hiding = Hiding(objects, poses, targets, rng) if t.occlusion > 0 and rng.uniform() < t.occlusion else None

    def score(T_cam_world: np.ndarray) -> float:
        eye = -T_cam_world[:3, :3].T @ T_cam_world[:3, 3]
        distances = np.linalg.norm(centres - eye, axis=1)
        blocked = caster.cast(eye, (centres - eye) / distances[:, None]) < distances - BLOCKING_MARGIN
        coverage = caster.view_coverage(K, T_cam_world, W, H) if t.min_view_coverage > 0 else 1.0
        if hiding is None:
            return coverage - float(blocked.any())  # any unblocked view beats every blocked one
        # enough of the environment in view counts as much as all of it; then the objects' hiding decides
        return min(coverage, t.min_view_coverage) - float(blocked.any()) + hiding_score(hiding.hidden(eye))

    # an occluding scene's tries stop early only at a perfect score (every object exactly half hidden)
    keys = orbit_key_poses(centres.mean(axis=0), keys_rng, t.key_poses, t.distance, t.elevation_deg,
                           t.azimuth_span_deg, t.jitter, score=score,
                           min_score=t.min_view_coverage + (1.0 if hiding is not None else 0.0),
                           redraw_azimuth=hiding is not None)
    return interpolate_poses(keys, cfg.frames_per_scene)

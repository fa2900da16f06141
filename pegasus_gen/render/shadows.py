"""Contact shadows and ambient occlusion for composed scenes: splats darkened where placed objects hide the sky.

A scan bakes the lighting of the place it was made in, so an object splat dropped into an environment casts
no shadow and the table under it stays as bright as before: the composition looks pasted. Here each splat
near a placed object is darkened by how much of the sky hemisphere (cosine-weighted about world up) the
*other* placed objects' meshes hide within ``radius`` of it, and optionally by how much of a key light's
cone they block. The darkening scales the splat's colour (its SH DC term and, as colour is linear in them,
every higher band), so it is the same for every render backend. Splats farther than ``radius`` from every
object's bounding sphere are not touched.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import open3d as o3d
import trimesh

from pegasus_gen.render.raycast import MeshRaycaster
from pegasus_gen.splats.cloud import SplatCloud
from pegasus_gen.splats.colour import transform_colour

# the shadows' occluders: an object's surface clustered to a grid of this many cells along its longest side
# (shadows are soft: a finer occluder only costs ray-cast time)
OCCLUDER_CELLS = 32
OCCLUDER_MIN_TRIANGLES = 4000  # surfaces with fewer triangles are used as they are
_OCCLUDERS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


@dataclass(frozen=True)
class ShadowParams:
    """How strong and how wide the shadows are; the defaults and checks are the generate config's ``shadows``
    section (``pegasus_gen.dataset.config.ShadowConfig``)."""

    radius: float  # m: occluders farther than this along a sky ray do not darken
    strength: float  # darkening at full occlusion: colour x (1 - strength)
    rays: int  # sky rays per splat
    light_direction: tuple[float, float, float] | None  # world, towards a key light
    light_weight: float  # share of the key light in the darkening (the sky has the rest)
    light_cone_deg: float  # half-angle of the light's cone (soft shadow edges)
    light_rays: int


def hemisphere_directions(count: int) -> np.ndarray:
    """[count, 3] unit directions over the upper (z >= 0) hemisphere, cosine-weighted: a Fibonacci spiral
    on the unit disc lifted onto the hemisphere (each direction stands for an equal share of the sky's
    irradiance on a horizontal surface)."""
    i = np.arange(count) + 0.5
    r = np.sqrt(i / count)
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - r**2)], axis=1)


def cone_directions(axis: np.ndarray, half_angle_deg: float, count: int) -> np.ndarray:
    """[count, 3] unit directions spread evenly (Fibonacci) over the cone of ``half_angle_deg`` about
    ``axis`` [3]."""
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    i = np.arange(count) + 0.5
    cos_t = 1.0 - (i / count) * (1.0 - np.cos(np.radians(half_angle_deg)))
    sin_t = np.sqrt(1.0 - cos_t**2)
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    helper = np.eye(3)[np.argmin(np.abs(axis))]
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    return (np.outer(cos_t, axis) + np.outer(sin_t * np.cos(phi), u) + np.outer(sin_t * np.sin(phi), v))


def occluder(surface: trimesh.Trimesh) -> trimesh.Trimesh:
    """``surface`` as the shadows' occluder: its vertices clustered to a grid of OCCLUDER_CELLS cells along its
    longest side (Open3D's vertex clustering, some thousand triangles), made once per surface object while it
    lives; surfaces of fewer than OCCLUDER_MIN_TRIANGLES triangles as they are."""
    if len(surface.faces) < OCCLUDER_MIN_TRIANGLES:
        return surface
    cached = _OCCLUDERS.get(surface)
    if cached is None:
        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(surface.vertices, np.float64)),
                                         o3d.utility.Vector3iVector(np.asarray(surface.faces, np.int32)))
        cell = float(np.ptp(np.asarray(surface.vertices), axis=0).max()) / OCCLUDER_CELLS
        coarse = mesh.simplify_vertex_clustering(voxel_size=cell)
        cached = _OCCLUDERS[surface] = trimesh.Trimesh(np.asarray(coarse.vertices), np.asarray(coarse.triangles),
                                                       process=False)
    return cached


def _blocked_fraction(points: np.ndarray, directions: np.ndarray, scene: MeshRaycaster, max_t: float,
                      rng: np.random.Generator, spin: bool) -> np.ndarray:
    """[N] fraction of the rays from each point [N, 3] along ``directions`` [R, 3] (unit) that hit ``scene`` within
    ``max_t``; with ``spin`` each point's set of directions is turned by a random angle about z (no banding
    from one shared set)."""
    n = len(points)
    d = np.asarray(directions, np.float32)
    if spin:
        angle = rng.uniform(0.0, 2.0 * np.pi, n)[:, None]
        c, s = np.cos(angle).astype(np.float32), np.sin(angle).astype(np.float32)
        d = np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], np.broadcast_to(d[:, 2], (n, len(d)))],
                     axis=-1)
    return scene.occluded(np.asarray(points)[:, None, :], d, max_t).mean(axis=1)  # [N, R]: each point, direction


def occlusion(points: np.ndarray, occluders: Sequence[trimesh.Trimesh], params: ShadowParams,
              rng: np.random.Generator) -> np.ndarray:
    """[N] darkening weight in 0..1 at each point [N, 3] (metres, world): the cosine-weighted share of the sky
    that ``occluders`` (meshes in the world frame) hide within ``params.radius``, mixed with the share of the
    key light's cone they block (any distance) when a light direction is given."""
    points = np.asarray(points, np.float64)
    if not len(points) or not occluders:
        return np.zeros(len(points))
    scene = MeshRaycaster(trimesh.util.concatenate(list(occluders)))
    sky = _blocked_fraction(points, hemisphere_directions(params.rays), scene, params.radius, rng, spin=True)
    if params.light_direction is None:
        return sky
    cone = cone_directions(np.asarray(params.light_direction), params.light_cone_deg, params.light_rays)
    light = _blocked_fraction(points, cone, scene, np.inf, rng, spin=False)
    return (1.0 - params.light_weight) * sky + params.light_weight * light


def darken(cloud: SplatCloud, factor: np.ndarray) -> SplatCloud:
    """The cloud with each splat's colour multiplied by ``factor`` [N] (0..1), on every SH band."""
    return transform_colour(cloud, np.asarray(factor, np.float64)[:, None, None] * np.eye(3))


def _enclosing_sphere(points: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre [3], radius): a sphere about the middle of the points' [N, 3] bounding box that holds them all. Not
    the smallest such sphere, which costs a convex hull per placed object and scene (20 ms each): about an irregular
    object a few more splats are shaded, none is missed."""
    centre = (points.min(axis=0) + points.max(axis=0)) / 2
    return centre, float(np.sqrt(((points - centre) ** 2).sum(axis=1).max()))


def _near(points: np.ndarray, spheres: list[tuple[np.ndarray, float]], radius: float) -> np.ndarray:
    """[K] int64 indices of the points [N, 3] within ``radius`` of any sphere (centre [3], radius), ascending. The
    spheres' distances are taken only inside the box that holds them all grown by ``radius`` (an environment's
    hundreds of thousands of splats are mostly outside it)."""
    if not spheres:
        return np.zeros(0, np.int64)
    reach = np.array([r + radius for _, r in spheres])
    centres = np.array([c for c, _ in spheres])
    # the box in the points' own precision, rounded outwards: no float64 copy of every point
    lo = np.nextafter((centres - reach[:, None]).min(axis=0).astype(points.dtype), -np.inf)
    hi = np.nextafter((centres + reach[:, None]).max(axis=0).astype(points.dtype), np.inf)
    inside = np.flatnonzero(np.all((points >= lo) & (points <= hi), axis=1))
    candidates, near = points[inside], np.zeros(len(inside), bool)
    for centre, r in zip(centres, reach):
        near |= np.linalg.norm(candidates - centre, axis=1) < r
    return inside[near]


def contact_shadows(environment: SplatCloud, objects: Sequence[SplatCloud], meshes: Sequence[trimesh.Trimesh],
                    params: ShadowParams, rng: np.random.Generator) -> tuple[SplatCloud, list[SplatCloud]]:
    """The environment's and the placed objects' splats (world frame) darkened by the placed objects' meshes
    (``meshes[k]``: object k's surface in the world frame): the environment by all of them, each object by
    the others. Returns (environment, objects)."""
    spheres = [_enclosing_sphere(np.asarray(m.vertices)) for m in meshes]

    def shade(cloud: SplatCloud, occluders: list[trimesh.Trimesh], others: list) -> SplatCloud:
        near = _near(cloud.means, others, params.radius)
        if not len(near):
            return cloud
        factor = 1.0 - params.strength * occlusion(cloud.means[near], occluders, params, rng)
        sh = cloud.sh.copy()  # only the near splats' colour changes: the rest are not recomputed
        sh[near] = darken(cloud.select(near), factor).sh
        return cloud.replace(sh=sh)

    shaded_env = shade(environment, list(meshes), spheres)
    shaded_objects = [shade(cloud, [m for j, m in enumerate(meshes) if j != k],
                            [s for j, s in enumerate(spheres) if j != k]) for k, cloud in enumerate(objects)]
    return shaded_env, shaded_objects

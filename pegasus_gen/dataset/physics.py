"""Physical placement with PyBullet (DIRECT): objects dropped onto an environment until they rest.

Poses come out as T_world_obj of each object's own frame (the frame of its splats, mesh and URDF
link). PyBullet reports a body's centre-of-mass frame; the URDF inertial origin converts it back.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from pegasus_gen.assets.library import Asset, DropRegion
from pegasus_gen.dataset.distractors import Distractor
from pegasus_gen.errors import PegasusError
from pegasus_gen.io.bullet import quiet_pybullet

pb = quiet_pybullet()


@dataclass(frozen=True)
class PhysicsParams:
    """Every knob of :func:`drop_objects`."""

    time_step: float = 1.0 / 240.0  # s
    gravity: float = 9.81  # m/s^2, along -z
    max_time: float = 8.0  # s of simulated time before giving up on rest
    rest_linear: float = 0.005  # m/s: an object moving slower is at rest ...
    rest_angular: float = 0.05  # rad/s ... and turning slower
    rest_hold: float = 0.25  # s every object must stay at rest
    drop_clearance: float = 0.03  # m between the support and an object's lowest possible point at spawn
    spacing_margin: float = 0.01  # m between the bounding spheres of spawned objects
    fell_below: float = 0.05  # m under the support height: the object left the support


UPRIGHT_TILT_DEG = 10.0  # an upright spawn leans at most this far from the asset's own z up


def random_quat_xyzw(rng: np.random.Generator) -> np.ndarray:
    """A uniformly distributed unit quaternion [4] (x, y, z, w): a normalised 4D Gaussian."""
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def upright_quat_xyzw(rng: np.random.Generator, max_tilt_deg: float = UPRIGHT_TILT_DEG) -> np.ndarray:
    """A rotation [4] (x, y, z, w) that keeps an asset standing as it was made (z up): a uniformly random turn
    about z, then a tilt of at most ``max_tilt_deg`` (uniform in angle) about a random horizontal axis."""
    yaw = rng.uniform(0.0, 2.0 * np.pi)
    tilt = np.radians(rng.uniform(0.0, max_tilt_deg))
    heading = rng.uniform(0.0, 2.0 * np.pi)
    lean = Rotation.from_rotvec(tilt * np.array([np.cos(heading), np.sin(heading), 0.0]))
    return (lean * Rotation.from_rotvec([0.0, 0.0, yaw])).as_quat()


def _matrix(position, quat_xyzw) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.asarray(pb.getMatrixFromQuaternion(quat_xyzw)).reshape(3, 3)
    T[:3, 3] = position
    return T


@dataclass
class DropResult:
    """poses: T_world_obj [4, 4] per kept object (index into the input list);
    removed: indices of objects that left the support; settle_time: simulated seconds;
    at_rest: whether everything came to rest before max_time;
    trajectory: per recorded frame (time s, {index: T_world_obj}) when recording was asked for."""

    poses: dict[int, np.ndarray]
    removed: list[int]
    settle_time: float
    at_rest: bool
    trajectory: list[tuple[float, dict[int, np.ndarray]]] = field(default_factory=list)


class World:
    """A PyBullet world holding one environment and some objects; poses in object frames."""

    def __init__(self, environment: Asset, params: PhysicsParams = PhysicsParams()):
        if environment.manifest.kind != "environment":
            raise PegasusError(f"{environment.name} is not an environment asset")
        self.params = params
        self.client = pb.connect(pb.DIRECT)
        pb.setGravity(0, 0, -params.gravity, physicsClientId=self.client)
        pb.setTimeStep(params.time_step, physicsClientId=self.client)
        self.environment = environment
        self.env_body = pb.loadURDF(str(environment.urdf_path), useFixedBase=True, physicsClientId=self.client)
        self.bodies: dict[int, int] = {}
        self._com_offsets: dict[int, np.ndarray] = {}

    def close(self) -> None:
        if self.client is not None:
            pb.disconnect(self.client)
            self.client = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def add(self, index: int, asset: Asset | Distractor, T_world_obj: np.ndarray) -> None:
        """Place object ``index`` (an asset, from its URDF, or a distractor, a convex body built from its
        mesh) with its object frame at T_world_obj [4, 4]."""
        from scipy.spatial.transform import Rotation

        quat = Rotation.from_matrix(T_world_obj[:3, :3]).as_quat()
        if isinstance(asset, Distractor):
            shape = pb.createCollisionShape(pb.GEOM_MESH, vertices=np.asarray(asset.mesh.vertices).tolist(),
                                            physicsClientId=self.client)
            body = pb.createMultiBody(asset.mass, shape, -1, T_world_obj[:3, 3].tolist(), quat.tolist(),
                                      physicsClientId=self.client)
            pb.changeDynamics(body, -1, lateralFriction=0.8, rollingFriction=0.002, spinningFriction=0.002,
                              restitution=0.05, physicsClientId=self.client)
        else:
            body = pb.loadURDF(str(asset.urdf_path), T_world_obj[:3, 3].tolist(), quat.tolist(),
                               physicsClientId=self.client)
        info = pb.getDynamicsInfo(body, -1, physicsClientId=self.client)
        self.bodies[index] = body
        self._com_offsets[index] = _matrix(info[3], info[4])  # T_obj_com from the URDF inertial origin

    def remove(self, index: int) -> None:
        pb.removeBody(self.bodies.pop(index), physicsClientId=self.client)
        self._com_offsets.pop(index)

    def pose(self, index: int) -> np.ndarray:
        """T_world_obj [4, 4] of object ``index`` (its own frame, not PyBullet's COM frame)."""
        position, quat = pb.getBasePositionAndOrientation(self.bodies[index], physicsClientId=self.client)
        return _matrix(position, quat) @ np.linalg.inv(self._com_offsets[index])

    def poses(self) -> dict[int, np.ndarray]:
        return {i: self.pose(i) for i in self.bodies}

    def at_rest(self) -> bool:
        for body in self.bodies.values():
            v, w = pb.getBaseVelocity(body, physicsClientId=self.client)
            if np.linalg.norm(v) > self.params.rest_linear or np.linalg.norm(w) > self.params.rest_angular:
                return False
        return True

    def step(self) -> None:
        pb.stepSimulation(physicsClientId=self.client)


def bounding_radius(body: Asset | Distractor) -> float:
    """The radius (m) of the sphere about the body's frame origin that holds its collision mesh."""
    return float(np.linalg.norm(body.mesh.vertices, axis=1).max())


PACKED_FILL = 1.0  # the objects' bounding circles' area over a packed region's (more than ~0.55 stacks some)


def packed_region(region: DropRegion, objects: list[Asset | Distractor], rng: np.random.Generator) -> DropRegion:
    """A square inside ``region`` (at a uniformly random place; the whole region where the square does not fit)
    whose area is the objects' bounding circles' over ``PACKED_FILL``: dropped there, they come to rest close
    together and hide one another from most views, as on a cluttered desk."""
    side = float(np.sqrt(sum(np.pi * bounding_radius(o) ** 2 for o in objects) / PACKED_FILL))
    corner = []
    for lo, hi in ((region.x_min, region.x_max), (region.y_min, region.y_max)):
        corner.append((lo, hi) if hi - lo <= side else (c := rng.uniform(lo, hi - side), c + side))
    (x_min, x_max), (y_min, y_max) = corner
    return DropRegion(x_min=x_min, x_max=x_max, y_min=y_min, y_max=y_max)


def spawn_poses(environment: Asset, objects: list[Asset | Distractor], rng: np.random.Generator,
                params: PhysicsParams = PhysicsParams(), orientations: Sequence | None = None,
                region: DropRegion | None = None) -> list[np.ndarray]:
    """Non-overlapping T_world_obj above ``region`` (default: the environment's drop region): object k turned by
    ``orientations[k]`` (a quaternion [4] x, y, z, w, one entry per object) where given and not None, else by a
    uniformly random rotation.

    Objects that do not fit side by side are stacked in layers above each other.
    """
    region = region or environment.manifest.drop_region
    support = environment.manifest.support_height
    radii = [bounding_radius(a) for a in objects]
    placed: list[tuple[np.ndarray, float]] = []
    poses = []
    layer_base = support + params.drop_clearance
    for k, radius in enumerate(radii):
        for _attempt in range(200):
            xy = rng.uniform([region.x_min, region.y_min], [region.x_max, region.y_max])
            centre = np.r_[xy, layer_base + radius]
            if all(np.linalg.norm(centre - c) >= radius + r + params.spacing_margin for c, r in placed):
                break
        else:  # no room in this layer: start a new one above everything placed so far
            layer_base = max(c[2] + r for c, r in placed) + params.spacing_margin
            centre = np.r_[rng.uniform([region.x_min, region.y_min], [region.x_max, region.y_max]),
                           layer_base + radius]
        placed.append((centre, radius))
        given = orientations[k] if orientations is not None else None
        T = _matrix(centre, random_quat_xyzw(rng) if given is None else given)
        poses.append(T)
    return poses


def drop_objects(environment: Asset, objects: list[Asset | Distractor], rng: np.random.Generator,
                 params: PhysicsParams = PhysicsParams(), record_fps: float | None = None,
                 orientations: Sequence | None = None, region: DropRegion | None = None) -> DropResult:
    """Drop ``objects`` onto ``environment`` (spawned over ``region`` turned by ``orientations``, see
    :func:`spawn_poses`) and simulate until all rest (or ``max_time``).

    With ``record_fps`` the poses are recorded at that rate from the spawn on (a dynamic scene).
    Objects that end below the support (fell off) are removed and listed in ``removed``.
    """
    with World(environment, params) as world:
        spawned = spawn_poses(environment, objects, rng, params, orientations, region)
        for i, (asset, T) in enumerate(zip(objects, spawned)):
            world.add(i, asset, T)
        steps_per_frame = None if not record_fps else max(1, int(round(1.0 / (record_fps * params.time_step))))
        trajectory = []
        rest_steps_needed = int(round(params.rest_hold / params.time_step))
        rest_steps = 0
        max_steps = int(round(params.max_time / params.time_step))
        step = 0
        while step < max_steps and rest_steps < rest_steps_needed:
            if steps_per_frame and step % steps_per_frame == 0:
                trajectory.append((step * params.time_step, world.poses()))
            world.step()
            step += 1
            rest_steps = rest_steps + 1 if world.at_rest() else 0
        at_rest = rest_steps >= rest_steps_needed
        floor = environment.manifest.support_height - params.fell_below
        removed = [i for i, T in world.poses().items() if T[2, 3] < floor]
        for i in removed:
            world.remove(i)
        return DropResult(world.poses(), removed, step * params.time_step, at_rest, trajectory)

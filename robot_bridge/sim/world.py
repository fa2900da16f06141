"""The simulated UR5 cell: a PyBullet world with the UR5 (URDF from the DH table), its parallel-jaw gripper,
a table top and objects, and the motions a UR controller executes (moveJ, moveL, stopJ/stopL).

The arm follows its trajectories exactly (joint states set each tick: a UR tracks its interpolated path to
well under a millimetre), the fingers are position-controlled with a force limit so they stop on what they
touch, and everything else is rigid-body physics. Holding: once the closed fingers both touch the same
object, it is fixed to the gripper body where it is (a PyBullet constraint) until the gripper opens;
friction between fingers and an arm that is moved kinematically lets objects slip in PyBullet, which a
real gripper's squeeze does not. Trajectories are trapezoidal velocity profiles: moveJ in
joint space (all joints start and stop together, the largest move at the given speed and acceleration),
moveL along the straight TCP line with the orientation SLERPed in step (the longer of translation at
``speed`` m/s and rotation at ``speed`` rad/s sets the time), each point solved by IK nearest the last
joints within the UR5's +-2 pi (a line that would turn a joint past it is refused before moving). A stop
decelerates along the current path at the given deceleration.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from pegasus_gen.io.bullet import quiet_pybullet
from robot_bridge.cell import SIM_CELL
from robot_bridge.kinematics import fk, nearest_ik
from robot_bridge.ur5_urdf import GRIPPER_FORCE, GRIPPER_STROKE, TCP_Z, ur5_urdf

pb = quiet_pybullet()

HOME_Q = np.array(SIM_CELL.home)  # rad: the cell's home joints (TCP pointing down in front of the base)


class MotionError(RuntimeError):
    """A motion the arm cannot make (target out of reach, no IK along a line)."""


@dataclass
class Profile:
    """Trapezoidal profile of a path length ``length`` >= 0 with peak speed ``v`` and acceleration ``a``."""

    length: float
    v: float
    a: float

    def __post_init__(self):
        self.v = max(min(self.v, np.sqrt(self.length * self.a)), 1e-9)  # triangle when too short to cruise
        self.t_acc = self.v / self.a
        self.d_acc = 0.5 * self.a * self.t_acc ** 2
        self.duration = 2 * self.t_acc + (self.length - 2 * self.d_acc) / self.v if self.length > 0 else 0.0

    def at(self, t: float) -> tuple[float, float]:
        """(s, ds/dt) at time t."""
        if t <= 0 or self.length <= 0:
            return 0.0, 0.0
        if t >= self.duration:
            return self.length, 0.0
        if t < self.t_acc:
            return 0.5 * self.a * t ** 2, self.a * t
        if t > self.duration - self.t_acc:
            r = self.duration - t
            return self.length - 0.5 * self.a * r ** 2, self.a * r
        return self.d_acc + self.v * (t - self.t_acc), self.v


class Motion:
    """A path s in [0, 1] -> joints, timed by a Profile; ``stop(a)`` turns it into a deceleration."""

    def __init__(self, joints_at, length: float, speed: float, acceleration: float):
        self.joints_at, self.length = joints_at, max(length, 0.0)
        self.profile = Profile(self.length, speed, acceleration)
        self.t = 0.0
        self.stopping: tuple[float, float, float, float] | None = None  # (t0, s0, v0, decel)

    def advance(self, dt: float) -> tuple[np.ndarray, bool]:
        """Joints after dt more seconds and whether the motion has ended."""
        self.t += dt
        if self.stopping is None:
            s, _ = self.profile.at(self.t)
            done = self.t >= self.profile.duration
        else:
            t0, s0, v0, a = self.stopping
            tau = min(self.t - t0, v0 / a)
            s = min(s0 + v0 * tau - 0.5 * a * tau ** 2, self.length)
            done = tau >= v0 / a
        return self.joints_at(s / self.length if self.length > 0 else 1.0), done

    def stop(self, deceleration: float) -> None:
        if self.stopping is None:
            s, v = self.profile.at(self.t)
            self.stopping = (self.t, s, v, max(deceleration, 1e-6))


def joint_motion(q_start, q_target, speed: float, acceleration: float) -> Motion:
    q_start, q_target = np.asarray(q_start, float), np.asarray(q_target, float)
    delta = q_target - q_start
    return Motion(lambda u: q_start + u * delta, float(np.abs(delta).max()), speed, acceleration)


def linear_motion(q_start, T_start: np.ndarray, T_target: np.ndarray, speed: float, acceleration: float,
                  tcp: np.ndarray) -> Motion:
    """moveL of the TCP from T_start to T_target (base frame); raises MotionError when a point of the line
    has no IK solution within the joint limits, or the joints jump between points (checked at 1 cm / 2 degree
    steps before moving)."""
    rotations = Slerp([0, 1], Rotation.from_matrix([T_start[:3, :3], T_target[:3, :3]]))
    distance = float(np.linalg.norm(T_target[:3, 3] - T_start[:3, 3]))
    angle = float((Rotation.from_matrix(T_target[:3, :3]) * Rotation.from_matrix(T_start[:3, :3]).inv()).magnitude())
    tcp_inv = np.linalg.inv(tcp)
    last = {"q": np.asarray(q_start, float)}

    def pose(u):
        T = np.eye(4)
        T[:3, :3] = rotations(u).as_matrix()
        T[:3, 3] = (1 - u) * T_start[:3, 3] + u * T_target[:3, 3]
        return T

    def joints_at(u):
        q = nearest_ik(pose(u) @ tcp_inv, last["q"])
        if q is None:
            raise MotionError(f"moveL: no inverse kinematics at {u:.0%} of the line")
        last["q"] = q
        return q

    steps = max(2, int(np.ceil(max(distance / 0.01, np.degrees(angle) / 2))))
    q = np.asarray(q_start, float)
    for u in np.linspace(0, 1, steps + 1)[1:]:  # check the whole line and the branch before moving
        q_next = nearest_ik(pose(u) @ tcp_inv, q)
        if q_next is None or np.abs(q_next - q).max() > 0.5:
            raise MotionError(f"moveL: the line leaves the reachable space, passes a singularity or would turn a "
                              f"joint past its limit at {u:.0%}")
        q = q_next
    return Motion(joints_at, max(distance, angle), speed, acceleration)


class RobotSim:
    """The UR5, its gripper and the world it acts in. ``client``: a PyBullet client to join (e.g. a
    ``pegasus_gen.dataset.physics.World``'s); by default its own, with a table top at z = 0 of the base frame."""

    def __init__(self, client: int | None = None, T_world_base: np.ndarray | None = None, q=HOME_Q,
                 time_step: float = 1.0 / 240.0):
        self.own_client = client is None
        self.client = pb.connect(pb.DIRECT) if client is None else client
        self.T_world_base = np.eye(4) if T_world_base is None else np.asarray(T_world_base, float)
        if self.own_client:
            pb.setGravity(0, 0, -9.81, physicsClientId=self.client)
            pb.setTimeStep(time_step, physicsClientId=self.client)
            table = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[1.0, 1.0, 0.02], physicsClientId=self.client)
            self.table = pb.createMultiBody(0, table, basePosition=[0, 0, -0.02], physicsClientId=self.client)
        self.time_step = pb.getPhysicsEngineParameters(physicsClientId=self.client)["fixedTimeStep"]
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "ur5_gripper.urdf"
            path.write_text(ur5_urdf(gripper=True))
            quat = Rotation.from_matrix(self.T_world_base[:3, :3]).as_quat()
            self.robot = pb.loadURDF(str(path), self.T_world_base[:3, 3].tolist(), quat.tolist(), useFixedBase=True,
                                     flags=pb.URDF_USE_SELF_COLLISION_EXCLUDE_PARENT, physicsClientId=self.client)
        names = [pb.getJointInfo(self.robot, j, physicsClientId=self.client)[1].decode()
                 for j in range(pb.getNumJoints(self.robot, physicsClientId=self.client))]
        self.fingers = [names.index("finger_left_joint"), names.index("finger_right_joint")]
        # links whose contact with anything is a collision: upper arm to wrist 3 and the gripper body (the
        # shoulder, link 0, sits on the mounting surface)
        self.gripper_link = names.index("gripper_mount")
        self.rigid_links = set(range(1, 6)) | {self.gripper_link}
        self.collision: str | None = None  # what the arm hit, once it has
        for link in self.fingers:
            pb.changeDynamics(self.robot, link, lateralFriction=1.5, physicsClientId=self.client)
        self.tcp = np.eye(4)
        self.tcp[2, 3] = TCP_Z  # T_flange_tcp; the controller's set_tcp changes it
        self.q = np.asarray(q, float).copy()
        self.qd = np.zeros(6)
        self.motion: Motion | None = None
        self.gripper_closed = False
        self.objects: dict[str, tuple[int, np.ndarray]] = {}  # name -> (body, T_obj_com)
        self.held: tuple[int, int] | None = None  # (object body, constraint) while the gripper holds one
        self.basket_box: tuple[np.ndarray, np.ndarray] | None = None  # (floor centre, size)
        self._set_joints(self.q, self.qd)
        self._time_debt = 0.0

    def add_object(self, name: str, urdf_path: str, T_base_obj: np.ndarray) -> None:
        """Load an object URDF with its object frame at T_base_obj (PyBullet keeps bodies at their centre of
        mass; the URDF's inertial origin is remembered to report object-frame poses)."""
        if name in self.objects:
            self.remove_object(name)
        T = self.T_world_base @ T_base_obj
        body = pb.loadURDF(str(urdf_path), T[:3, 3].tolist(), Rotation.from_matrix(T[:3, :3]).as_quat().tolist(),
                           physicsClientId=self.client)
        info = pb.getDynamicsInfo(body, -1, physicsClientId=self.client)
        T_obj_com = np.eye(4)
        T_obj_com[:3, :3] = Rotation.from_quat(info[4]).as_matrix()
        T_obj_com[:3, 3] = info[3]
        self.objects[name] = (body, T_obj_com)

    def object_pose(self, name: str) -> np.ndarray:
        """T_base_obj [4, 4] of a loaded object."""
        body, T_obj_com = self.objects[name]
        position, quat = pb.getBasePositionAndOrientation(body, physicsClientId=self.client)
        T_world_com = np.eye(4)
        T_world_com[:3, :3] = Rotation.from_quat(quat).as_matrix()
        T_world_com[:3, 3] = position
        return np.linalg.inv(self.T_world_base) @ T_world_com @ np.linalg.inv(T_obj_com)

    def remove_object(self, name: str) -> None:
        body = self.objects.pop(name)[0]
        if self.held is not None and self.held[0] == body:
            pb.removeConstraint(self.held[1], physicsClientId=self.client)
            self.held = None
        pb.removeBody(body, physicsClientId=self.client)

    def add_basket(self, centre, size=(0.24, 0.24, 0.08), wall: float = 0.006) -> None:
        """An open box standing on the table: floor centre ``centre`` [3] (base frame), outer ``size`` (m)."""
        sx, sy, h = size
        parts = [((sx / 2, sy / 2, wall / 2), (0, 0, wall / 2)),
                 ((wall / 2, sy / 2, h / 2), (sx / 2 - wall / 2, 0, h / 2)),
                 ((wall / 2, sy / 2, h / 2), (-sx / 2 + wall / 2, 0, h / 2)),
                 ((sx / 2, wall / 2, h / 2), (0, sy / 2 - wall / 2, h / 2)),
                 ((sx / 2, wall / 2, h / 2), (0, -sy / 2 + wall / 2, h / 2))]
        shapes = [pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=self.client)
                  for half, _ in parts]
        T = self.T_world_base.copy()
        T[:3, 3] = (self.T_world_base @ np.r_[centre, 1.0])[:3]
        self.basket = pb.createMultiBody(0, -1, basePosition=T[:3, 3].tolist(),
                                         linkMasses=[0] * 5, linkCollisionShapeIndices=shapes,
                                         linkVisualShapeIndices=[-1] * 5,
                                         linkPositions=[list(o) for _, o in parts],
                                         linkOrientations=[[0, 0, 0, 1]] * 5,
                                         linkInertialFramePositions=[[0, 0, 0]] * 5,
                                         linkInertialFrameOrientations=[[0, 0, 0, 1]] * 5, linkParentIndices=[0] * 5,
                                         linkJointTypes=[pb.JOINT_FIXED] * 5, linkJointAxis=[[0, 0, 1]] * 5,
                                         physicsClientId=self.client)
        self.basket_box = (np.asarray(centre, float), np.asarray(size, float))

    def in_basket(self, name: str) -> bool:
        """Whether the object's origin lies inside the basket's walls, below their top."""
        if self.basket_box is None:
            return False
        (cx, cy, cz), (sx, sy, h) = self.basket_box
        x, y, z = self.object_pose(name)[:3, 3]
        return abs(x - cx) < sx / 2 and abs(y - cy) < sy / 2 and cz < z < cz + h + 0.05

    def close(self) -> None:
        if self.own_client and self.client is not None:
            pb.disconnect(self.client)
        self.client = None

    def _set_joints(self, q, qd) -> None:
        for j in range(6):
            pb.resetJointState(self.robot, j, q[j], qd[j], physicsClientId=self.client)

    def tcp_pose(self) -> np.ndarray:
        """T_base_tcp [4, 4] of the current joints."""
        return fk(self.q, self.tcp)

    def move_joints(self, q_target, speed: float, acceleration: float) -> None:
        self.motion = joint_motion(self.q, q_target, speed, acceleration)

    def move_linear(self, T_target: np.ndarray, speed: float, acceleration: float) -> None:
        self.motion = linear_motion(self.q, self.tcp_pose(), T_target, speed, acceleration, self.tcp)

    def stop(self, deceleration: float) -> None:
        if self.motion is not None:
            self.motion.stop(deceleration)

    @property
    def moving(self) -> bool:
        return self.motion is not None

    def set_gripper(self, closed: bool) -> None:
        self.gripper_closed = bool(closed)
        if not closed and self.held is not None:
            pb.removeConstraint(self.held[1], physicsClientId=self.client)
            self.held = None

    def _hold_if_gripped(self) -> None:
        """Fix an object touched by both closed fingers to the gripper body."""
        if not self.gripper_closed or self.held is not None:
            return
        touching = [{c[2] for c in pb.getContactPoints(bodyA=self.robot, linkIndexA=f, physicsClientId=self.client)
                     if c[2] != self.robot} for f in self.fingers]
        common = touching[0] & touching[1] & {body for body, _ in self.objects.values()}
        if not common:
            return
        body = min(common)
        state = pb.getLinkState(self.robot, self.gripper_link, physicsClientId=self.client)
        pos, quat = pb.getBasePositionAndOrientation(body, physicsClientId=self.client)
        inv_pos, inv_quat = pb.invertTransform(state[4], state[5])
        rel_pos, rel_quat = pb.multiplyTransforms(inv_pos, inv_quat, pos, quat)
        constraint = pb.createConstraint(self.robot, self.gripper_link, body, -1, pb.JOINT_FIXED, [0, 0, 0],
                                         rel_pos, [0, 0, 0], rel_quat, physicsClientId=self.client)
        pb.changeConstraint(constraint, maxForce=200, physicsClientId=self.client)
        self.held = (body, constraint)

    def gripper_width(self) -> float:
        """Distance between the fingers, m."""
        travel = sum(pb.getJointState(self.robot, j, physicsClientId=self.client)[0] for j in self.fingers)
        return GRIPPER_STROKE - travel

    def advance(self, dt: float) -> None:
        """Run the cell for dt seconds: the arm along its motion, the fingers, physics."""
        if self.motion is not None:
            q_prev = self.q
            try:
                self.q, done = self.motion.advance(dt)
            except MotionError:
                self.motion, done = None, True
            self.qd = (self.q - q_prev) / dt
            if done:
                self.motion, self.qd = None, np.zeros(6)
        self._time_debt += dt
        target = GRIPPER_STROKE / 2 if self.gripper_closed else 0.0
        pb.setJointMotorControlArray(self.robot, self.fingers, pb.POSITION_CONTROL, targetPositions=[target] * 2,
                                     forces=[GRIPPER_FORCE] * 2, physicsClientId=self.client)
        while self._time_debt >= self.time_step:
            self._set_joints(self.q, self.qd)
            pb.stepSimulation(physicsClientId=self.client)
            self._time_debt -= self.time_step
        self._set_joints(self.q, self.qd)
        self._hold_if_gripped()
        for contact in pb.getContactPoints(bodyA=self.robot, physicsClientId=self.client):
            other, link, depth = contact[2], contact[3], -contact[8]
            if other == self.robot or depth < 0.001:
                continue
            static = pb.getDynamicsInfo(other, -1, physicsClientId=self.client)[0] == 0
            if link in self.rigid_links or (link in self.fingers and static):  # fingers may touch what they grasp
                self.collision = f"robot link {link} hit body {other} ({depth * 1000:.1f} mm deep)"
                self.motion, self.qd = None, np.zeros(6)
                break

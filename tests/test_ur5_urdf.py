"""The UR5 URDF built from the DH table: PyBullet's flange pose equals the DH forward kinematics, and the
arm holds a pose under gravity with position control."""

import numpy as np
import pybullet as p
import pytest
from scipy.spatial.transform import Rotation

from robot_bridge.kinematics import fk
from robot_bridge.ur5_urdf import JOINT_NAMES, ur5_urdf


@pytest.fixture
def arm(tmp_path):
    path = tmp_path / "ur5.urdf"
    path.write_text(ur5_urdf())
    client = p.connect(p.DIRECT)
    robot = p.loadURDF(str(path), useFixedBase=True, physicsClientId=client)
    yield client, robot
    p.disconnect(client)


def flange_pose(client, robot):
    names = [p.getJointInfo(robot, j, physicsClientId=client)[12].decode() for j in
             range(p.getNumJoints(robot, physicsClientId=client))]
    state = p.getLinkState(robot, names.index("flange"), computeForwardKinematics=True, physicsClientId=client)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(state[5]).as_matrix()
    T[:3, 3] = state[4]
    return T


def test_pybullet_flange_pose_equals_dh_forward_kinematics(arm):
    client, robot = arm
    joints = [p.getJointInfo(robot, j, physicsClientId=client)[1].decode() for j in range(6)]
    assert tuple(joints) == JOINT_NAMES
    rng = np.random.default_rng(0)
    for q in rng.uniform(-np.pi, np.pi, (30, 6)):
        for j, angle in enumerate(q):
            p.resetJointState(robot, j, angle, physicsClientId=client)
        np.testing.assert_allclose(flange_pose(client, robot), fk(q), atol=1e-6)


def test_arm_holds_a_pose_under_gravity(arm):
    client, robot = arm
    p.setGravity(0, 0, -9.81, physicsClientId=client)
    q = np.array([0.2, -1.3, 1.6, -1.9, -1.57, 0.3])
    for j, angle in enumerate(q):
        p.resetJointState(robot, j, angle, physicsClientId=client)
    p.setJointMotorControlArray(robot, list(range(6)), p.POSITION_CONTROL, targetPositions=q,
                                forces=[150, 150, 150, 28, 28, 28], physicsClientId=client)
    for _ in range(480):
        p.stepSimulation(physicsClientId=client)
    reached = np.array([s[0] for s in p.getJointStates(robot, list(range(6)), physicsClientId=client)])
    assert np.abs(reached - q).max() < 2e-3
    assert np.linalg.norm(flange_pose(client, robot)[:3, 3] - fk(q)[:3, 3]) < 2e-3

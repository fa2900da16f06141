"""A UR5 URDF built from the DH table (no meshes to download): the simulated controller's arm.

Link frames: link i (i = 1..6) sits where DH frame i-1 is turned by joint i about its z axis, so joint i's
URDF origin is the fixed part of DH row i-1 (Tz(d) Tx(a) Rx(alpha); identity for joint 1) and its axis is
z. A fixed joint adds the last DH row to reach ``flange`` (T_base_flange as ``kinematics.fk``), and
``base_link`` is the controller's base frame. Each link is a cylinder from its origin to the next joint
(the DH offsets d along z, then a along x) plus a joint housing; masses are UR's, inertias those of the
cylinders (uniform rods of radius ``LINK_RADIUS``).
"""

from __future__ import annotations

import numpy as np

from robot_bridge.kinematics import ALPHA, JOINT_LIMIT, LINK_MASSES, A, D

JOINT_NAMES = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
               "wrist_3_joint")
LINK_RADIUS = 0.045  # m
MAX_JOINT_SPEED = 3.15  # rad/s (UR5: 180 deg/s)
MAX_JOINT_TORQUE = (150.0, 150.0, 150.0, 28.0, 28.0, 28.0)  # N m
# Parallel-jaw gripper on the flange (flange frame: z along the tool): a body, two fingers sliding along y.
GRIPPER_BODY = (0.06, 0.18, 0.07)  # m, x y z
FINGER = (0.025, 0.012, 0.075)  # m, x y z
GRIPPER_STROKE = 0.14  # m, widest opening between the fingers (as a Robotiq 2F-140: cup noodles are 9.4 cm wide)
GRIPPER_FORCE = 60.0  # N per finger
TCP_Z = GRIPPER_BODY[2] + FINGER[2] - 0.015  # m: the TCP sits between the fingertips


def _rpy_of_rx(alpha: float) -> str:
    return f"{alpha:.9f} 0 0"


def _segment(start: np.ndarray, end: np.ndarray, radius: float) -> str:
    """A cylinder <origin>/<geometry> pair from ``start`` to ``end`` (link frame, m); empty when they meet."""
    v = end - start
    length = float(np.linalg.norm(v))
    if length < 1e-6:
        return ""
    z = v / length
    # rotation taking +z onto v, as roll-pitch-yaw (only about y then z is needed for a direction)
    pitch = float(np.arccos(np.clip(z[2], -1, 1)))
    yaw = float(np.arctan2(z[1], z[0]))
    mid = (start + end) / 2
    shape = f'<cylinder radius="{radius}" length="{length:.6f}"/>'
    origin = f'<origin xyz="{mid[0]:.6f} {mid[1]:.6f} {mid[2]:.6f}" rpy="0 {pitch:.9f} {yaw:.9f}"/>'
    return (f"<visual>{origin}<geometry>{shape}</geometry></visual>"
            f"<collision>{origin}<geometry>{shape}</geometry></collision>")


def _link(i: int) -> str:
    """Link i (1..6): the body between joint i and joint i+1 (or the flange)."""
    end = np.array([A[i - 1], 0.0, D[i - 1]])
    corner = np.array([0.0, 0.0, D[i - 1]])
    housing = _segment(np.array([0.0, 0.0, -0.06]), np.array([0.0, 0.0, 0.06]), LINK_RADIUS * 1.25)
    body = _segment(np.zeros(3), corner, LINK_RADIUS) + _segment(corner, end, LINK_RADIUS)
    mass = LINK_MASSES[i - 1]
    length = max(abs(A[i - 1]) + abs(D[i - 1]), 0.12)
    com = end / 2
    ixx = mass * (3 * LINK_RADIUS ** 2 + length ** 2) / 12
    izz = mass * LINK_RADIUS ** 2 / 2
    inertial = (f'<inertial><origin xyz="{com[0]:.6f} {com[1]:.6f} {com[2]:.6f}"/><mass value="{mass}"/>'
                f'<inertia ixx="{ixx:.6g}" iyy="{ixx:.6g}" izz="{izz:.6g}" ixy="0" ixz="0" iyz="0"/></inertial>')
    return f'<link name="link_{i}">{inertial}{housing}{body}</link>'


def _box_link(name: str, size, xyz, mass: float) -> str:
    sx, sy, sz = size
    shape = f'<box size="{sx} {sy} {sz}"/>'
    origin = f'<origin xyz="{xyz[0]} {xyz[1]} {xyz[2]}"/>'
    i = mass / 12
    return (f'<link name="{name}"><inertial>{origin}<mass value="{mass}"/><inertia ixx="{i * (sy**2 + sz**2):.4g}" '
            f'iyy="{i * (sx**2 + sz**2):.4g}" izz="{i * (sx**2 + sy**2):.4g}" ixy="0" ixz="0" iyz="0"/></inertial>'
            f"<visual>{origin}<geometry>{shape}</geometry></visual>"
            f"<collision>{origin}<geometry>{shape}</geometry></collision></link>")


def _gripper() -> list[str]:
    """The gripper body on the flange, fingers ``finger_left``/``finger_right`` (prismatic, 0 = open to
    0.5 * GRIPPER_STROKE = closed, each moving towards the centre) and a ``tcp`` link."""
    bx, by, bz = GRIPPER_BODY
    fx, fy, fz = FINGER
    half = GRIPPER_STROKE / 2
    parts = [_box_link("gripper_body", GRIPPER_BODY, (0, 0, bz / 2), 0.9),
             '<joint name="gripper_mount" type="fixed"><parent link="flange"/><child link="gripper_body"/>'
             '<origin xyz="0 0 0"/></joint>']
    for name, side in (("finger_left", 1), ("finger_right", -1)):
        parts.append(_box_link(name, FINGER, (0, side * fy / 2, fz / 2), 0.08))
        parts.append(f'<joint name="{name}_joint" type="prismatic"><parent link="gripper_body"/><child link="{name}"/>'
                     f'<origin xyz="0 {side * half} {bz}"/><axis xyz="0 {-side} 0"/>'
                     f'<limit lower="0" upper="{half}" effort="{GRIPPER_FORCE}" velocity="0.15"/></joint>')
    parts.append('<link name="tcp"><inertial><mass value="0.001"/>'
                 '<inertia ixx="1e-7" iyy="1e-7" izz="1e-7" ixy="0" ixz="0" iyz="0"/></inertial></link>')
    parts.append(f'<joint name="tcp_joint" type="fixed"><parent link="flange"/><child link="tcp"/>'
                 f'<origin xyz="0 0 {TCP_Z}"/></joint>')
    return parts


def ur5_urdf(gripper: bool = False) -> str:
    """The URDF text: base_link, link_1..link_6 on the six revolute joints (JOINT_NAMES), flange, and with
    ``gripper`` the parallel-jaw gripper and its ``tcp`` link (TCP_Z in front of the flange)."""
    parts = ['<?xml version="1.0"?>', '<robot name="ur5_dh">',
             '<link name="base_link"><inertial><mass value="4.0"/>'
             '<inertia ixx="0.0061" iyy="0.0061" izz="0.0056" ixy="0" ixz="0" iyz="0"/></inertial>'
             + _segment(np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.03]), 0.075) + "</link>"]
    parent = "base_link"
    for i in range(1, 7):
        parts.append(_link(i))
        if i == 1:
            origin = '<origin xyz="0 0 0" rpy="0 0 0"/>'
        else:
            origin = f'<origin xyz="{A[i - 2]} 0 {D[i - 2]}" rpy="{_rpy_of_rx(ALPHA[i - 2])}"/>'
        parts.append(f'<joint name="{JOINT_NAMES[i - 1]}" type="revolute"><parent link="{parent}"/>'
                     f'<child link="link_{i}"/>{origin}<axis xyz="0 0 1"/>'
                     f'<limit lower="{-JOINT_LIMIT}" upper="{JOINT_LIMIT}" effort="{MAX_JOINT_TORQUE[i - 1]}" '
                     f'velocity="{MAX_JOINT_SPEED}"/></joint>')
        parent = f"link_{i}"
    parts.append('<link name="flange"><inertial><mass value="0.001"/>'
                 '<inertia ixx="1e-7" iyy="1e-7" izz="1e-7" ixy="0" ixz="0" iyz="0"/></inertial></link>')
    parts.append(f'<joint name="flange_joint" type="fixed"><parent link="link_6"/><child link="flange"/>'
                 f'<origin xyz="{A[5]} 0 {D[5]}" rpy="{_rpy_of_rx(ALPHA[5])}"/></joint>')
    if gripper:
        parts += _gripper()
    parts.append("</robot>")
    return "\n".join(parts) + "\n"

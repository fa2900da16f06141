"""The safety envelope: every limit refuses with its reason; joint moves are checked along the way."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pegasus_gen.errors import PegasusError
from robot_bridge.kinematics import fk, matrix_to_rtde_pose
from robot_bridge.safety import SafetyEnvelope, UnsafeCommand

TOOL_DOWN = np.array([0.0, -1.8, 1.8, -1.57, -1.57, 0.0])  # TCP at (-0.39, -0.11, 0.42), tool pointing down


def test_each_limit_refuses_with_its_reason():
    env = SafetyEnvelope(x=(-0.6, 0.6), y=(-0.6, 0.6), z=(-0.1, 0.8), table_z=0.02, min_height=0.01)
    home = fk(TOOL_DOWN)
    env.check_pose(home)
    env.check_pose(matrix_to_rtde_pose(home))
    cases = {"x = 0.700": [0.7, 0, 0.3], "y = -0.650": [0.1, -0.65, 0.3], "above the table top": [0.1, 0.1, 0.025]}
    for reason, xyz in cases.items():
        T = home.copy()
        T[:3, 3] = xyz
        with pytest.raises(UnsafeCommand, match=reason):
            env.check_pose(T)
    tilted = home.copy()
    a = np.radians(70)
    tilted[:3, :3] = home[:3, :3] @ np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    with pytest.raises(UnsafeCommand, match="tilted 70.0 deg"):
        env.check_pose(tilted)
    for speed, acc in ((0.0, 1.0), (0.6, 1.0), (0.2, 2.0)):
        with pytest.raises(UnsafeCommand, match="refused"):
            env.check_linear(home, home, speed, acc)
    with pytest.raises(PegasusError, match="max_tilt_deg"):
        SafetyEnvelope(max_tilt_deg=95)


def test_joint_move_with_safe_ends_but_an_unsafe_middle_is_refused():
    env = SafetyEnvelope(y=(-0.3, 0.8))
    start = TOOL_DOWN.copy()  # pan 0: TCP at y = -0.11
    end = TOOL_DOWN.copy()
    end[0] = np.pi  # pan pi: TCP at y = +0.11; turning through pan pi/2 passes y = -0.39
    env.check_pose(fk(start))
    env.check_pose(fk(end))
    with pytest.raises(UnsafeCommand, match="moveJ refused at .* y = -0.3"):
        env.check_joint(start, end, 0.5, 1.0)
    end[0] = -np.pi  # the other way round passes y = +0.39: inside
    env.check_joint(start, end, 0.5, 1.0)


def test_the_pose_checked_is_the_pose_sent_and_the_whole_linear_path():
    """A scaled rotation (read raw, 50 deg; sent as its nearest rotation, 70 deg), a NaN, a SLERP that
    leaves the tilt cone between two ends inside it, a zero speed, a joint target ten turns away."""
    env = SafetyEnvelope()
    home = fk(TOOL_DOWN)
    scaled = home.copy()
    a = np.radians(70)
    scaled[:3, :3] = home[:3, :3] @ np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    scaled[:3, :3] *= np.cos(np.radians(50)) / np.cos(a)  # -T[2, 2] now reads as a 50 degree tilt
    assert np.degrees(np.arccos(-scaled[2, 2])) < env.max_tilt_deg
    with pytest.raises(UnsafeCommand, match="not a rigid transform"):
        env.check_pose(scaled)
    for bad in ([0.1, -0.3, 0.3, np.nan, 0.0, 0.0], [0.1, -0.3, np.inf, 3.14, 0.0, 0.0]):
        with pytest.raises(UnsafeCommand, match="NaN or infinite"):
            env.check_pose(bad)

    # ends tilted 48.9 and 44.7 degrees; the SLERP between them reaches 68.0 degrees
    ends = [home.copy(), home.copy()]
    for T, rotvec in zip(ends, ([1.0, -2.6, 1.26], [2.46, 1.48, 1.18])):
        T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
        env.check_pose(T)
    with pytest.raises(UnsafeCommand, match=r"moveL refused at \d+% of the way: the tool is tilted 6"):
        env.check_linear(ends[0], ends[1], 0.1, 1.0)
    env.check_linear(ends[0], ends[0], 0.1, 1.0)  # staying put is fine

    with pytest.raises(UnsafeCommand, match="speed 0"):
        env.check_linear(home, home, 0.0, 1.0)
    far = TOOL_DOWN + [20 * np.pi, 0, 0, 0, 0, 0]  # the same TCP pose, ten base turns away
    np.testing.assert_allclose(fk(far), home, atol=1e-9)
    with pytest.raises(UnsafeCommand, match="joint 0 = 62.832 rad beyond the joint limit"):
        env.check_joint(TOOL_DOWN, far, 0.5, 1.0)
    with pytest.raises(UnsafeCommand, match="6 finite angles"):
        env.check_joint(TOOL_DOWN, TOOL_DOWN + [0, np.nan, 0, 0, 0, 0], 0.5, 1.0)


@pytest.mark.parametrize("kwargs", [{"table_z": np.nan}, {"min_height": np.nan}, {"min_height": np.inf},
                                    {"joint_limit": np.nan}, {"joint_limit": 7.0}, {"joint_limit": 0.0},
                                    {"samples": 0}, {"samples": 1}, {"samples": 2.5}, {"samples": True},
                                    {"x": (-np.inf, np.inf)}, {"z": (np.nan, 0.9)}, {"max_tilt_deg": np.nan},
                                    {"max_speed": np.nan}, {"max_joint_acceleration": 0.0}])
def test_a_parameter_that_would_switch_a_check_off_is_refused(kwargs):
    """NaN compares false: SafetyEnvelope(table_z=nan) let a move into the table through (issue 31, H6)."""
    name = next(iter(kwargs))
    with pytest.raises(PegasusError, match=name):
        SafetyEnvelope(**kwargs)


def test_an_absurd_rotation_vector_is_refused_with_the_envelopes_error():
    """A rotation vector of 1e300 rad is no rotation in floating point: UnsafeCommand, not a LinAlgError."""
    env = SafetyEnvelope()
    for bad in ([-0.4, -0.1, 0.3, 1e300, 0.0, 0.0], [-0.4, -0.1, 0.3, 0.0, 7.0, 0.0]):
        with pytest.raises(UnsafeCommand, match="rotation vector is .* rad long"):
            env.check_pose(bad)
        with pytest.raises(UnsafeCommand, match="rotation vector is .* rad long"):
            env.check_linear(fk(TOOL_DOWN), bad, 0.1, 1.0)

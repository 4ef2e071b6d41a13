"""NED/FRD <-> ENU/FLU conversions: round trips and known attitudes."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from companion import frames
from sitl.physics.frames import quaternion_from_euler, rotation_from_euler

angle = st.floats(-3.0, 3.0)
small_pitch = st.floats(-1.4, 1.4)
vec = st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3)

A_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
B_FLU_FRD = np.diag([1.0, -1.0, -1.0])


@given(vec)
def test_world_and_body_vectors_round_trip(v):
    np.testing.assert_allclose(frames.enu_from_ned(frames.ned_from_enu(v)), v)
    np.testing.assert_allclose(frames.flu_from_frd(frames.frd_from_flu(v)), v)


def test_known_vectors():
    # 1 m east, 2 m north, 3 m up is 2 m north, 1 m east, 3 m up (-3 down).
    np.testing.assert_allclose(frames.ned_from_enu([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    # A roll rate to the right (FRD +x unchanged), pitch up (FRD +y), yaw right (FRD +z).
    np.testing.assert_allclose(frames.frd_from_flu([0.1, 0.2, 0.3]), [0.1, -0.2, -0.3])


@given(angle, small_pitch, angle)
def test_quaternion_conjugation_matches_matrices(phi, theta, psi):
    q_enu = quaternion_from_euler(phi, theta, psi)
    q_ned = frames.quaternion_ned_frd_from_enu_flu(q_enu)
    expected = A_NED_ENU @ rotation_from_euler(phi, theta, psi) @ B_FLU_FRD
    np.testing.assert_allclose(frames.rotation_from_quaternion(q_ned), expected, atol=1e-12)
    back = frames.quaternion_enu_flu_from_ned_frd(q_ned)
    sign = 1.0 if np.dot(back, q_enu) >= 0 else -1.0
    np.testing.assert_allclose(sign * back, q_enu, atol=1e-12)


@given(angle, small_pitch, angle)
def test_euler_matches_quaternion(phi, theta, psi):
    roll, pitch, yaw = frames.euler_ned_frd_from_enu_flu(phi, theta, psi)
    # PX4's ZYX angles of the NED/FRD rotation, from the conjugated matrix.
    r = A_NED_ENU @ rotation_from_euler(phi, theta, psi) @ B_FLU_FRD
    assert roll == pytest.approx(math.atan2(r[2, 1], r[2, 2]), abs=1e-9)
    assert pitch == pytest.approx(-math.asin(r[2, 0]), abs=1e-9)
    assert math.remainder(yaw - math.atan2(r[1, 0], r[0, 0]), 2 * math.pi) == pytest.approx(
        0.0, abs=1e-9
    )
    back = frames.euler_enu_flu_from_ned_frd(roll, pitch, yaw)
    assert back[0] == pytest.approx(phi)
    assert back[1] == pytest.approx(theta)
    assert math.remainder(back[2] - psi, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)


def test_level_facing_east_is_yaw_90_in_ned():
    q_ned = frames.quaternion_ned_frd_from_enu_flu([1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(
        frames.rotation_from_quaternion(q_ned) @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12
    )
    assert frames.euler_ned_frd_from_enu_flu(0.0, 0.0, 0.0)[2] == pytest.approx(math.pi / 2)


@pytest.mark.parametrize("bad", [[0, 0, 0, 0], [math.nan, 0, 0, 1], [math.inf, 0, 0, 0]])
def test_corrupt_quaternion_is_rejected(bad):
    with pytest.raises(ValueError, match="not a rotation quaternion"):
        frames.quaternion_enu_flu_from_ned_frd(bad)

"""Telemetry decoding: PX4's NED/FRD messages become ENU/FLU samples; garbage is refused."""

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as m

from companion.link import (
    BodyRates,
    ImuSample,
    LandedState,
    TelemetryDecoder,
    TelemetryError,
    TimesyncReply,
    VehiclePose,
    VehicleStatus,
    px4_mode,
)
from companion.link.setpoint import quaternion_from_euler_zyx

NAN = float("nan")
C45 = math.sqrt(0.5)


def odometry(q=(1, 0, 0, 0), xyz=(1.0, 2.0, -3.0), v=(0.5, 0.0, 0.0), child=m.MAV_FRAME_LOCAL_NED,
             frame=m.MAV_FRAME_LOCAL_NED, rates=(0.1, 0.2, 0.3), time_usec=12_345_678):  # fmt: skip
    return m.MAVLink_odometry_message(
        time_usec, frame, child, *xyz, list(q), *v, *rates, [NAN] * 21, [NAN] * 21, 0, 0, 0
    )


def test_odometry_pose_in_enu_flu():
    pose, rates = TelemetryDecoder("odometry").decode(odometry())
    assert isinstance(pose, VehiclePose) and isinstance(rates, BodyRates)
    assert pose.time_boot_ms == 12_345
    assert pose.position_enu_m == pytest.approx((2.0, 1.0, 3.0))  # NED (1, 2, -3): 3 m up
    assert pose.velocity_enu_m_s == pytest.approx((0.0, 0.5, 0.0))  # 0.5 m/s north
    # Level, nose north in NED = yaw +90 deg about ENU's up axis.
    assert pose.q_enu_flu == pytest.approx((C45, 0.0, 0.0, C45))
    assert pose.euler_zyx_rad() == pytest.approx((0.0, 0.0, math.pi / 2))
    assert rates.omega_flu_rad_s == pytest.approx((0.1, -0.2, -0.3))


def test_odometry_body_velocity_is_rotated_into_the_world():
    q_ned = quaternion_from_euler_zyx(0.0, 0.0, math.pi / 2)  # nose east in NED
    (pose, _) = TelemetryDecoder().decode(
        odometry(q=q_ned, v=(1.0, 0, 0), child=m.MAV_FRAME_BODY_FRD)
    )
    assert pose.velocity_enu_m_s == pytest.approx((1.0, 0.0, 0.0), abs=1e-7)  # forward = east
    assert pose.euler_zyx_rad() == pytest.approx((0.0, 0.0, 0.0), abs=1e-7)


def test_euler_angles_of_a_tilted_pose():
    q_enu = quaternion_from_euler_zyx(0.1, -0.2, 0.3)
    pose = VehiclePose(0, (0.0, 0.0, 0.0), None, q_enu)
    assert pose.euler_zyx_rad() == pytest.approx((0.1, -0.2, 0.3))


@pytest.mark.parametrize(
    ("msg", "reason"),
    [
        (odometry(xyz=(NAN, 0, 0)), "bad_position"),
        (odometry(q=(0, 0, 0, 0)), "bad_quaternion"),
        (odometry(q=(2, 0, 0, 0)), "bad_quaternion"),
        (odometry(q=(NAN, 0, 0, 0)), "bad_quaternion"),
        (odometry(rates=(0, float("inf"), 0)), "bad_rates"),
        (odometry(frame=m.MAV_FRAME_LOCAL_FRD), "unsupported_frame"),
        (odometry(child=m.MAV_FRAME_LOCAL_FRD), "unsupported_frame"),
    ],
)
def test_garbage_is_refused_with_a_reason(msg, reason):
    with pytest.raises(TelemetryError) as info:
        TelemetryDecoder().decode(msg)
    assert info.value.reason == reason


def test_nan_velocity_means_unknown_velocity():
    (pose, _) = TelemetryDecoder().decode(odometry(v=(NAN, NAN, NAN)))
    assert pose.velocity_enu_m_s is None


def test_local_position_needs_an_attitude_first():
    decoder = TelemetryDecoder("local_position")
    lpn = m.MAVLink_local_position_ned_message(500, 1.0, 2.0, -3.0, 0.0, 0.0, -1.0)
    with pytest.raises(TelemetryError) as info:
        decoder.decode(lpn)
    assert info.value.reason == "no_attitude_yet"
    att = m.MAVLink_attitude_quaternion_message(490, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5, [0] * 4)
    (rates,) = decoder.decode(att)
    assert rates.time_boot_ms == 490 and rates.omega_flu_rad_s == pytest.approx((0, 0, -0.5))
    (pose,) = decoder.decode(lpn)
    assert pose.time_boot_ms == 500
    assert pose.position_enu_m == pytest.approx((2.0, 1.0, 3.0))
    assert pose.velocity_enu_m_s == pytest.approx((0.0, 0.0, 1.0))
    assert decoder.decode(odometry()) == ()  # one pose source only


def test_imu_specific_force_at_rest_points_up_in_flu():
    imu = m.MAVLink_highres_imu_message(
        2_000_000, 0.1, 0.2, -9.81, 0.01, 0.02, 0.03, 0, 0, 0, 0, 0, 0, 0, 0x3F
    )
    (sample,) = TelemetryDecoder().decode(imu)
    assert isinstance(sample, ImuSample)
    assert sample.time_boot_ms == 2000
    assert sample.specific_force_flu_m_s2 == pytest.approx((0.1, -0.2, 9.81))
    assert sample.omega_flu_rad_s == pytest.approx((0.01, -0.02, -0.03))


def test_heartbeat_and_landed_state():
    decoder = TelemetryDecoder()
    decoder.decode(odometry(time_usec=7_000_000))
    armed = m.MAV_MODE_FLAG_SAFETY_ARMED | m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    hb = m.MAVLink_heartbeat_message(
        m.MAV_TYPE_HEXAROTOR, m.MAV_AUTOPILOT_PX4, armed, px4_mode("OFFBOARD").custom_mode, 4, 3
    )
    (status,) = decoder.decode(hb)
    assert isinstance(status, VehicleStatus)
    assert (status.armed, status.mode_name, status.time_boot_ms) == (True, "OFFBOARD", 7000)
    (landed,) = decoder.decode(m.MAVLink_extended_sys_state_message(0, m.MAV_LANDED_STATE_IN_AIR))
    assert isinstance(landed, LandedState)
    assert (landed.name, landed.on_ground) == ("IN_AIR", False)
    with pytest.raises(TelemetryError):
        decoder.decode(m.MAVLink_extended_sys_state_message(0, 42))


def test_a_timesync_answer_is_a_reply_and_the_vehicles_own_request_is_not():
    decoder = TelemetryDecoder()
    assert decoder.decode(m.MAVLink_timesync_message(0, 5_000_000_000)) == ()
    (reply,) = decoder.decode(m.MAVLink_timesync_message(5_020_000_000, 5_000_000_000))
    assert reply == TimesyncReply(5_020_000_000, 5_000_000_000)


def test_unknown_pose_source_is_refused():
    with pytest.raises(ValueError):
        TelemetryDecoder("mocap")  # type: ignore[arg-type]


def test_quaternion_from_euler_matches_rotation_matrix():
    from companion.frames import rotation_from_quaternion

    phi, theta, psi = 0.3, -0.4, 2.5
    rz = np.array(
        [[math.cos(psi), -math.sin(psi), 0], [math.sin(psi), math.cos(psi), 0], [0, 0, 1]]
    )
    ry = np.array(
        [[math.cos(theta), 0, math.sin(theta)], [0, 1, 0], [-math.sin(theta), 0, math.cos(theta)]]
    )
    rx = np.array(
        [[1, 0, 0], [0, math.cos(phi), -math.sin(phi)], [0, math.sin(phi), math.cos(phi)]]
    )
    r = rotation_from_quaternion(quaternion_from_euler_zyx(phi, theta, psi))
    np.testing.assert_allclose(r, rz @ ry @ rx, atol=1e-12)

"""The OFFBOARD handover state (companion.mission.offboard): its transitions, the setpoint of each
stage, when PX4 has left OFFBOARD, and the force PX4's Hold needed before the handover."""

from __future__ import annotations

import numpy as np
import pytest

from companion.control.laws import DesiredState
from companion.control.setpoints import AttitudeThrustSetpoint, ThrustModel
from companion.link.px4_modes import px4_mode
from companion.link.telemetry import VehicleStatus
from companion.mission.offboard import (
    TRANSITIONS,
    HoldBias,
    Offboard,
    Stream,
    StreamTransitionError,
)

THRUST = ThrustModel(36.0, 0.1)
Q = np.array([1.0, 2.0, 3.0, 0.05, -0.04, 0.7, 0.0, -1.5])
CONTROL_SP = AttitudeThrustSetpoint(0.1, 0.2, 0.7, 14.0, 14.0 / 36.0, False, False)


def test_the_way_in_is_off_hold_control_and_nothing_skips_the_handover():
    o = Offboard()
    with pytest.raises(StreamTransitionError, match="off -> control"):
        o.accept(1.0)
    o.to(Stream.HOLD)
    assert not o.flying
    o.accept(12.5)
    assert o.flying and o.accepted_s == 12.5
    with pytest.raises(StreamTransitionError, match="control -> hold"):
        o.to(Stream.HOLD)


@pytest.mark.parametrize("way_out", [Stream.LEVEL, Stream.GROUND])
def test_a_way_out_leads_only_to_off(way_out):
    o = Offboard()
    o.to(Stream.HOLD)
    o.accept(0.0)
    o.to(way_out)
    other = Stream.GROUND if way_out == Stream.LEVEL else Stream.LEVEL
    with pytest.raises(StreamTransitionError):
        o.to(other)
    o.to(Stream.OFF)
    o.to(way_out)  # landing after a hold: from OFF again
    assert all(Stream.OFF in TRANSITIONS[s] or s == Stream.OFF for s in Stream)


def test_each_stage_streams_its_setpoint():
    o = Offboard()
    weight = 13.0
    assert o.setpoint(CONTROL_SP, Q, weight, THRUST) is None
    o.to(Stream.HOLD)
    hold = o.setpoint(CONTROL_SP, Q, weight, THRUST)
    assert (hold.roll_rad, hold.pitch_rad, hold.yaw_rad) == (0.05, -0.04, 0.7)
    assert hold.thrust_n == pytest.approx(weight)
    o.accept(0.0)
    assert o.setpoint(CONTROL_SP, Q, weight, THRUST) is CONTROL_SP
    o.to(Stream.LEVEL)
    level = o.setpoint(CONTROL_SP, Q, weight, THRUST)
    assert (level.roll_rad, level.pitch_rad, level.yaw_rad, level.thrust_n) == pytest.approx(
        (0.0, 0.0, 0.7, weight)
    )
    o.to(Stream.OFF)
    o.to(Stream.GROUND)
    ground = o.setpoint(CONTROL_SP, Q, weight, THRUST)
    assert (ground.roll_rad, ground.pitch_rad) == (0.0, 0.0)
    assert ground.thrust_relative == pytest.approx(0.1)  # PX4's MPC_THR_MIN, not zero


def test_with_px4_flying_position_the_air_stages_stream_position_targets():
    """HOLD and LEVEL: where the vehicle is, at rest (PX4 brakes and holds); CONTROL: the
    mission's desired position, velocity, acceleration and yaw; GROUND and OFF: none (the
    ground stays an attitude setpoint)."""
    o = Offboard()
    q_d = np.array([4.0, 5.0, 6.0, 0.0, 0.0, 0.2, 0.0, 0.0])
    desired = DesiredState(q_d, np.arange(8.0) * 0.1, np.arange(8.0) * -0.2)
    assert o.position_setpoint(Q, desired) is None
    o.to(Stream.HOLD)
    hold = o.position_setpoint(Q, desired)
    assert (hold.position_m, hold.velocity_m_s, hold.yaw_rad) == ((1.0, 2.0, 3.0), (0, 0, 0), 0.7)
    assert hold.acceleration_m_s2 == (0.0, 0.0, 0.0)
    o.accept(0.0)
    control = o.position_setpoint(Q, desired)
    assert control.position_m == (4.0, 5.0, 6.0) and control.yaw_rad == 0.2
    assert control.velocity_m_s == pytest.approx((0.0, 0.1, 0.2))
    assert control.acceleration_m_s2 == pytest.approx((0.0, -0.2, -0.4))
    o.to(Stream.LEVEL)
    assert o.position_setpoint(Q, desired).position_m == (1.0, 2.0, 3.0)
    o.to(Stream.OFF)
    o.to(Stream.GROUND)
    assert o.position_setpoint(Q, desired) is None


def status(time_boot_ms, mode):
    return VehicleStatus(time_boot_ms, True, px4_mode(mode), 4)


def test_offboard_left_only_after_a_heartbeat_that_had_time_to_show_it():
    """HEARTBEAT is 1 Hz: one sent just after the acknowledgement still shows Hold."""
    o = Offboard()
    o.to(Stream.HOLD)
    o.accept(10.0)
    assert not o.left(None)
    assert not o.left(status(10_100, "LOITER"))
    assert not o.left(status(11_000, "OFFBOARD"))
    assert o.left(status(11_000, "LOITER"))


def test_hold_bias_is_the_mean_force_less_mass_times_the_mean_acceleration():
    bias = HoldBias(window_s=3.0)
    assert np.array_equal(bias.force_n(1.5), np.zeros(2))
    for i in range(500):  # 5 s at 100 Hz: the first 2 s fall out of the window
        t = 0.01 * i
        force = np.array([0.3, -0.2]) if t >= 1.5 else np.array([9.0, 9.0])
        bias.record(t, force, np.array([0.1 * t, 0.0]))
    np.testing.assert_allclose(bias.force_n(1.5), [0.3 - 1.5 * 0.1, -0.2], atol=1e-9)

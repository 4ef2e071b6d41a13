"""The pure simulated PX4 (sitl.px4.vehicle): modes, commands, offboard, params, telemetry."""

import math
import os
import struct

os.environ.setdefault("MAVLINK20", "1")

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M

from companion.frames import quaternion_ned_frd_from_enu_flu
from sitl.physics.frames import quaternion_from_euler
from sitl.px4 import PARAMETERS, Px4Mode, Px4Params, Px4Vehicle, VehicleMeasurement

GCS = (255, 190)
_client = M.MAVLink(None, *GCS)


def received(msg):
    """``msg`` as the vehicle gets it from a GCS (255/190): packed and decoded."""
    parser = M.MAVLink(None)
    return parser.parse_buffer(msg.pack(_client))[0]


def measurement(t=0.0, pos=(0.0, 0.0, 0.0), vel=(0.0, 0.0, 0.0), yaw=0.0, on_ground=True):
    return VehicleMeasurement(
        t,
        pos,
        vel,
        quaternion_from_euler(0.0, 0.0, yaw),
        [0.0, 0.0, 0.0],
        [0, 0, 9.81],
        on_ground,
        16.0,
        0.9,
    )


def command(cmd, *params):
    p = list(params) + [0.0] * (7 - len(params))
    return received(M.MAVLink_command_long_message(1, 1, cmd, 0, *p))


def acks(replies):
    return [m for _, m in replies if m.get_type() == "COMMAND_ACK"]


def attitude_target(q_ned=(1.0, 0.0, 0.0, 0.0), thrust=0.6, mask=0b111):
    return received(M.MAVLink_set_attitude_target_message(0, 1, 1, mask, q_ned, 0, 0, 0, thrust))


@pytest.fixture
def vehicle():
    v = Px4Vehicle(Px4Params())
    v.control(0.0, measurement())
    return v


def set_mode(vehicle, mode, t):
    return acks(vehicle.handle(command(176, 1, mode.main_mode, mode.sub_mode), "onboard", t))[0]


# ------------------------------------------------------------------ modes


@pytest.mark.parametrize("name", sorted(set(mavutil.px4_map) - {"RATTITUDE", "RTGS", "FOLLOWME"}))
def test_mode_encoding_round_trips_through_pymavlink(name):
    base, main, sub = mavutil.px4_map[name]
    mode = Px4Mode.from_main_sub(main, sub)
    assert mode is not None
    assert mavutil.interpret_px4_mode(base, mode.custom_mode) == name
    assert Px4Mode.from_custom_mode(mode.custom_mode) is mode


def test_unknown_mode_numbers_decode_to_none():
    assert Px4Mode.from_main_sub(4, 0) is None
    assert Px4Mode.from_main_sub(42, 0) is None


def test_heartbeat_is_px4_hexarotor_and_shows_arming_and_mode(vehicle):
    beats = [m for _, m in vehicle.telemetry(0.0, measurement()) if m.get_type() == "HEARTBEAT"]
    assert len(beats) == 2  # one per link
    hb = beats[0]
    assert (hb.type, hb.autopilot) == (M.MAV_TYPE_HEXAROTOR, M.MAV_AUTOPILOT_PX4)
    assert mavutil.interpret_px4_mode(hb.base_mode, hb.custom_mode) == "LOITER"
    assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert acks(vehicle.handle(command(400, 1), "onboard", 0.1))[0].result == M.MAV_RESULT_ACCEPTED
    beats = [m for _, m in vehicle.telemetry(0.1, measurement(0.1)) if m.get_type() == "HEARTBEAT"]
    assert beats and beats[0].base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED  # at once, not in 1 s


# --------------------------------------------------------------- commands


def test_command_ack_is_addressed_to_the_sender_on_its_link(vehicle):
    replies = vehicle.handle(command(400, 1), "gcs", 0.0)
    (link, ack), *_ = [(lk, m) for lk, m in replies if m.get_type() == "COMMAND_ACK"]
    assert link == "gcs"
    assert (ack.command, ack.target_system, ack.target_component) == (400, *GCS)


def test_unhandled_command_is_unsupported_and_foreign_target_is_ignored(vehicle):
    assert (
        acks(vehicle.handle(command(M.MAV_CMD_DO_SET_SERVO, 1, 1500), "gcs", 0.0))[0].result
        == M.MAV_RESULT_UNSUPPORTED
    )
    other = received(M.MAVLink_command_long_message(7, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
    assert vehicle.handle(other, "gcs", 0.0) == []
    assert vehicle.counters["not_for_us"] == 1 and not vehicle.armed


def test_request_message_answers_autopilot_version_and_home(vehicle):
    replies = vehicle.handle(command(512, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION), "onboard", 0.0)
    version = next(m for _, m in replies if m.get_type() == "AUTOPILOT_VERSION")
    assert version.capabilities & M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    assert version.capabilities & M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    assert version.flight_sw_version >> 24 == 1
    replies = vehicle.handle(command(512, M.MAVLINK_MSG_ID_HOME_POSITION), "onboard", 0.0)
    assert [m.get_type() for _, m in replies] == ["HOME_POSITION", "COMMAND_ACK"]
    replies = vehicle.handle(command(520, 1), "onboard", 0.0)
    assert [m.get_type() for _, m in replies] == ["AUTOPILOT_VERSION", "COMMAND_ACK"]
    assert acks(vehicle.handle(command(512, 9999), "onboard", 0.0))[0].result == M.MAV_RESULT_DENIED


def test_disarm_in_air_is_denied_unless_forced(vehicle):
    vehicle.handle(command(400, 1), "onboard", 0.0)
    vehicle.control(0.1, measurement(0.1, pos=(0, 0, 2), on_ground=False))
    replies = vehicle.handle(command(400, 0), "onboard", 0.2)
    assert acks(replies)[0].result == M.MAV_RESULT_DENIED
    assert any(m.get_type() == "STATUSTEXT" for _, m in replies)
    assert vehicle.armed
    assert acks(vehicle.handle(command(400, 0, 21196), "onboard", 0.3))[0].result == 0
    assert not vehicle.armed


def test_set_mode_message_is_acked_as_do_set_mode(vehicle):
    custom = Px4Mode.POSCTL.custom_mode
    msg = received(M.MAVLink_set_mode_message(1, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom))
    (ack,) = acks(vehicle.handle(msg, "gcs", 0.0))
    assert (ack.command, ack.result) == (M.MAV_CMD_DO_SET_MODE, M.MAV_RESULT_ACCEPTED)
    assert vehicle.mode is Px4Mode.POSCTL


def test_manual_modes_are_rejected_without_sticks(vehicle):
    assert set_mode(vehicle, Px4Mode.STABILIZED, 0.0).result == M.MAV_RESULT_TEMPORARILY_REJECTED
    assert set_mode(vehicle, Px4Mode.AUTO_MISSION, 0.0).result == M.MAV_RESULT_DENIED
    assert vehicle.mode is Px4Mode.AUTO_LOITER


# --------------------------------------------------------------- offboard


def test_offboard_needs_a_live_setpoint_stream(vehicle):
    assert set_mode(vehicle, Px4Mode.OFFBOARD, 0.0).result == M.MAV_RESULT_TEMPORARILY_REJECTED
    vehicle.handle(attitude_target(), "onboard", 0.5)
    assert set_mode(vehicle, Px4Mode.OFFBOARD, 1.4).result == M.MAV_RESULT_ACCEPTED  # < 1 s old
    assert vehicle.mode is Px4Mode.OFFBOARD


def test_stale_stream_is_rejected_after_com_of_loss_t(vehicle):
    vehicle.handle(attitude_target(), "onboard", 0.0)
    assert set_mode(vehicle, Px4Mode.OFFBOARD, 1.0).result == M.MAV_RESULT_TEMPORARILY_REJECTED


def test_setpoints_apply_only_in_offboard_and_convert_to_enu_flu(vehicle):
    q_enu = quaternion_from_euler(0.1, -0.05, 0.4)
    vehicle.handle(attitude_target(quaternion_ned_frd_from_enu_flu(q_enu), 0.55), "onboard", 0.0)
    vehicle.handle(command(400, 1), "onboard", 0.0)
    held = vehicle.control(0.001, measurement(0.001))
    assert held.thrust == 0.0  # Hold on the ground: idle, not the offboard thrust
    set_mode(vehicle, Px4Mode.OFFBOARD, 0.002)
    sp = vehicle.control(0.003, measurement(0.003))
    assert sp.thrust == pytest.approx(0.55, abs=1e-6)
    assert abs(float(np.dot(sp.quaternion_wxyz, q_enu))) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize(
    ("q", "thrust", "reason"),
    [
        ((math.nan, 0.0, 0.0, 1.0), 0.5, "invalid_setpoint"),
        ((0.0, 0.0, 0.0, 0.0), 0.5, "invalid_setpoint"),
        ((1.0, 0.0, 0.0, 0.0), 1.5, "invalid_setpoint"),
        ((1.0, 0.0, 0.0, 0.0), math.nan, "invalid_setpoint"),
    ],
)
def test_malformed_setpoints_are_counted_and_are_no_proof_of_life(vehicle, q, thrust, reason):
    assert vehicle.handle(attitude_target(q, thrust), "onboard", 0.0) == []
    assert vehicle.counters[reason] == 1
    assert not vehicle.offboard_alive(0.0)


def test_rate_setpoints_are_counted_as_unsupported(vehicle):
    vehicle.handle(attitude_target(mask=M.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE), "onboard", 0)
    assert vehicle.counters["rate_setpoint_unsupported"] == 1
    assert not vehicle.offboard_alive(0.0)


@pytest.mark.parametrize(("action", "mode"), [(5, Px4Mode.AUTO_LOITER), (4, Px4Mode.AUTO_LAND),
                                              (0, Px4Mode.POSCTL)])  # fmt: skip
def test_offboard_loss_fails_safe_after_com_of_loss_t_of_sim_time(action, mode):
    vehicle = Px4Vehicle(Px4Params({"COM_OBL_RC_ACT": action, "COM_OF_LOSS_T": 0.5}))
    air = dict(pos=(0.0, 0.0, 3.0), on_ground=False)
    vehicle.handle(attitude_target(), "onboard", 0.0)
    vehicle.handle(command(400, 1), "onboard", 0.0)
    set_mode(vehicle, Px4Mode.OFFBOARD, 0.0)
    t = 0.0
    while t < 0.499:
        vehicle.control(t, measurement(t, **air))
        t += 0.001
    assert vehicle.mode is Px4Mode.OFFBOARD and not vehicle.failsafe
    vehicle.control(0.5, measurement(0.5, **air))
    assert vehicle.mode is mode and vehicle.failsafe
    out = vehicle.telemetry(0.5, measurement(0.5, **air))
    hb = next(m for _, m in out if m.get_type() == "HEARTBEAT")
    assert Px4Mode.from_custom_mode(hb.custom_mode) is mode
    assert hb.system_status == M.MAV_STATE_CRITICAL
    assert any(m.get_type() == "STATUSTEXT" for _, m in out)


# -------------------------------------------------------------- telemetry


def count_streams(vehicle, seconds, dt=0.001, start=0.0):
    counts = {}
    steps = round(seconds / dt)
    for k in range(steps):
        t = start + k * dt
        for link, msg in vehicle.telemetry(t, measurement(t)):
            counts[(link, msg.get_type())] = counts.get((link, msg.get_type()), 0) + 1
    return counts


def test_onboard_rates_over_simulated_time():
    vehicle = Px4Vehicle(Px4Params())
    counts = count_streams(vehicle, 2.0)
    expected = {"ATTITUDE": 200, "ATTITUDE_QUATERNION": 100, "HIGHRES_IMU": 100,
                "LOCAL_POSITION_NED": 60, "ODOMETRY": 60, "SYS_STATUS": 10,
                "EXTENDED_SYS_STATE": 10, "ALTITUDE": 20, "HEARTBEAT": 2}  # fmt: skip
    for kind, n in expected.items():
        assert counts[("onboard", kind)] == n, kind
    assert counts[("gcs", "ATTITUDE")] == 40


def test_set_message_interval_changes_one_link_only():
    vehicle = Px4Vehicle(Px4Params())
    interval = command(511, M.MAVLINK_MSG_ID_ATTITUDE, 1e6 / 7.0)
    assert acks(vehicle.handle(interval, "onboard", 0.0))[0].result == M.MAV_RESULT_ACCEPTED
    off = command(511, M.MAVLINK_MSG_ID_HIGHRES_IMU, -1)
    assert acks(vehicle.handle(off, "onboard", 0.0))[0].result == M.MAV_RESULT_ACCEPTED
    unknown = command(511, M.MAVLINK_MSG_ID_VFR_HUD, 1e5)
    assert acks(vehicle.handle(unknown, "onboard", 0.0))[0].result == M.MAV_RESULT_FAILED
    counts = count_streams(vehicle, 2.0)
    assert counts[("onboard", "ATTITUDE")] == 14
    assert ("onboard", "HIGHRES_IMU") not in counts
    assert counts[("gcs", "ATTITUDE")] == 40
    reply = vehicle.handle(command(510, M.MAVLINK_MSG_ID_ATTITUDE), "onboard", 2.0)
    assert reply[0][1].interval_us == round(1e6 / 7.0)


def test_measurement_copies_and_freezes_its_vectors_and_names_a_bad_one():
    pos, vel, omega, force = np.array([1.0, 2, 3]), np.zeros(3), np.zeros(3), np.zeros(3)
    quat = quaternion_from_euler(0.0, 0.0, 0.5)
    m = VehicleMeasurement(0.5, pos, vel, quat, omega, force, False)
    pos[0] = 9.0  # the caller's array is copied
    assert m.position_enu_m.tolist() == [1.0, 2.0, 3.0]
    assert m.quaternion_enu_flu_wxyz.tolist() == quat.tolist()
    for arr in (m.position_enu_m, m.velocity_enu_m_s, m.quaternion_enu_flu_wxyz):
        assert not arr.flags.writeable
    # lists and other shapes take the per-field path: the same values
    other = VehicleMeasurement(0.5, [9, 2, 3], [[0, 0, 0]], list(quat), omega, force, False)
    assert other.velocity_enu_m_s.shape == (3,) and other.position_enu_m.dtype == np.float64
    bad = np.array([0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="omega_flu_rad_s"):
        VehicleMeasurement(0.5, pos, vel, quat, bad, force, False)
    with pytest.raises(ValueError, match="velocity_enu_m_s"):
        VehicleMeasurement(0.5, pos, np.zeros(4), quat, omega, force, False)
    # finite vectors whose values together overflow a float sum are still finite ones
    huge = np.array([1e308, 0.0, 0.0])
    m = VehicleMeasurement(0.5, huge, huge, quat, omega, force, False)
    assert m.position_enu_m[0] == m.velocity_enu_m_s[0] == 1e308


def test_ping_request_is_returned_to_its_sender_and_answers_are_not(vehicle):
    out = vehicle.handle(received(M.MAVLink_ping_message(123_456, 7, 0, 0)), "onboard", 1.0)
    assert len(out) == 1
    link, pong = out[0]
    assert link == "onboard" and pong.get_type() == "PING"
    assert (pong.time_usec, pong.seq) == (123_456, 7)
    assert (pong.target_system, pong.target_component) == GCS
    answer = M.MAVLink_ping_message(5, 8, 1, 1)  # a reply to a ping of the vehicle's
    assert vehicle.handle(received(answer), "gcs", 1.0) == []
    assert vehicle.counters["ignored_message"] == 0


def test_stream_scheduler_due_times_through_disable_enable_and_trigger():
    from sitl.px4.telemetry import StreamScheduler

    hb, att = M.MAVLINK_MSG_ID_HEARTBEAT, M.MAVLINK_MSG_ID_ATTITUDE
    s = StreamScheduler({hb: 1.0, att: 100.0})
    assert sorted(s.due(0)) == sorted([hb, att])
    assert s.due(5_000) == [] and s.due(10_000) == [att]
    s.trigger(hb, 12_000)  # due at once, before the next attitude
    assert s.due(12_000) == [hb] and s.due(13_000) == []
    s.set_interval(att, -1, 13_000)
    s.set_interval(hb, -1, 13_000)
    assert not any(s.due(t) for t in range(13_000, 2_100_000, 1_000))
    s.set_interval(att, 0, 2_500_000)  # back to the default, due from now
    assert s.due(2_499_000) == [] and s.due(2_500_000) == [att]
    assert s.due(2_505_000) == [] and s.due(2_510_000) == [att]
    s.trigger(hb, 2_511_000)  # a disabled stream stays disabled
    assert s.due(2_511_000) == []
    assert s.due(2_600_000) == [att]  # a late caller: sent once, rescheduled from now
    assert s.due(2_605_000) == [] and s.due(2_610_000) == [att]


def test_telemetry_is_ned_frd_of_a_known_enu_measurement():
    vehicle = Px4Vehicle(Px4Params())
    m = VehicleMeasurement(
        1.25, [1.0, 2.0, 3.0], [0.1, 0.2, 0.3], quaternion_from_euler(0.0, 0.0, 0.0),
        [0.01, 0.02, 0.03], [0.0, 0.0, 9.81], False, 15.2, 0.5,
    )  # fmt: skip
    msgs = {msg.get_type(): msg for _, msg in vehicle.telemetry(1.25, m)}
    lp = msgs["LOCAL_POSITION_NED"]
    assert (lp.x, lp.y, lp.z, lp.vx, lp.vy, lp.vz) == pytest.approx((2, 1, -3, 0.2, 0.1, -0.3))
    assert lp.time_boot_ms == 1250
    att = msgs["ATTITUDE"]  # nose east: NED yaw +90 deg
    assert (att.roll, att.pitch, att.yaw) == pytest.approx((0.0, 0.0, math.pi / 2))
    assert (att.rollspeed, att.pitchspeed, att.yawspeed) == pytest.approx((0.01, -0.02, -0.03))
    imu = msgs["HIGHRES_IMU"]
    assert (imu.xacc, imu.yacc, imu.zacc) == pytest.approx((0.0, 0.0, -9.81))
    odo = msgs["ODOMETRY"]  # velocity in body FRD: east-facing nose, so forward = east
    assert (odo.vx, odo.vy, odo.vz) == pytest.approx((0.1, -0.2, -0.3), abs=1e-6)
    gp = msgs["GLOBAL_POSITION_INT"]
    assert gp.lat > round(vehicle.geo.latitude_deg * 1e7)
    assert gp.relative_alt == 3000 and gp.hdg == 9000
    assert msgs["SYS_STATUS"].voltage_battery == 15200
    assert msgs["SYS_STATUS"].onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK


# ----------------------------------------------------------------- params


def test_param_list_is_complete_and_indexed(vehicle):
    out = vehicle.handle(received(M.MAVLink_param_request_list_message(1, 1)), "gcs", 0.0)
    values = [m for _, m in out]
    assert [m.param_index for m in values] == list(range(len(PARAMETERS)))
    assert {m.param_id for m in values} == set(PARAMETERS)
    assert all(m.param_count == len(PARAMETERS) for m in values)


def test_int32_params_are_encoded_bytewise(vehicle):
    out = vehicle.handle(received(M.MAVLink_param_request_read_message(1, 1, b"MAV_SYS_ID", -1)),
                         "gcs", 0.0)  # fmt: skip
    (value,) = [m for _, m in out]
    assert value.param_type == M.MAV_PARAM_TYPE_INT32
    assert struct.unpack("<i", struct.pack("<f", value.param_value))[0] == 1
    by_index = M.MAVLink_param_request_read_message(1, 1, b"", value.param_index)
    assert vehicle.handle(received(by_index), "gcs", 0.0)[0][1].param_id == "MAV_SYS_ID"


def test_param_set_accepts_refuses_and_reports_unknown(vehicle):
    def param_set(name, wire):
        msg = M.MAVLink_param_set_message(1, 1, name.encode(), wire, M.MAV_PARAM_TYPE_REAL32)
        return vehicle.handle(received(msg), "gcs", 0.0)

    out = param_set("MIS_TAKEOFF_ALT", 4.0)
    assert [(link, m.param_value) for link, m in out] == [("onboard", 4.0), ("gcs", 4.0)]
    assert vehicle.params["MIS_TAKEOFF_ALT"] == 4.0
    bytewise_4 = struct.unpack("<f", struct.pack("<i", 4))[0]
    param_set("COM_OBL_RC_ACT", bytewise_4)
    assert vehicle.params["COM_OBL_RC_ACT"] == 4
    out = param_set("COM_OBL_RC_ACT", struct.unpack("<f", struct.pack("<i", 3))[0])  # RTL
    assert vehicle.params["COM_OBL_RC_ACT"] == 4
    assert [m.get_type() for _, m in out] == ["PARAM_VALUE", "STATUSTEXT", "STATUSTEXT"]
    out = param_set("COM_OF_LOSS_T", math.nan)
    assert vehicle.params["COM_OF_LOSS_T"] == 1.0 and out[0][1].param_value == 1.0
    out = param_set("NO_SUCH_PARAM", 1.0)
    assert [m.text for _, m in out] == ["[pm] unknown param: NO_SUCH_PARAM"] * 2


def test_hover_thrust_from_scenario_hovers_the_nominal_airframe():
    from companion.config import load_scenario
    from sitl.physics.rotors import thrust_curve

    scenario = load_scenario("configs/paper_sim_flight.toml")
    params = Px4Params.from_scenario(scenario)
    rotors = scenario.vehicle.rotors
    thrust = (
        6
        * rotors.max_thrust_per_rotor_n
        * thrust_curve(params["MPC_THR_HOVER"], rotors.thr_mdl_fac)
    )
    assert thrust == pytest.approx(1.2 * scenario.environment.gravity_m_s2, rel=1e-9)
    assert params["THR_MDL_FAC"] == rotors.thr_mdl_fac

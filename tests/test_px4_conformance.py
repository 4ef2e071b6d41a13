"""The conformance suite: every scenario of ``tests/px4_conformance.py`` on both peers.

The expectations are PX4 main's, measured on the real SITL build; the imitation must meet
them except where :attr:`px4_conformance.Peer.differences` says why not (then the test
checks the imitation's documented behaviour). PX4 peers need ``PX4_SITL_DIR`` (skipped
with the reason otherwise). Each peer boots once per aiding mode (a module-scoped
fixture); one peer runs at a time. Set ``PX4_CONFORMANCE_FIGURES=path.json`` to keep the
figures each scenario measured.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from px4_conformance import (
    INT32_PARAMS,
    LAND,
    LOITER,
    NOT_IMITATED,
    OFFBOARD,
    PX4_DEFAULTS,
    PX4_ONBOARD_RATES_HZ,
    RTL,
    ImitationPeer,
    Peer,
    Px4Peer,
    commands,
    flight,
    heartbeat_around_a_mode_change,
    motion_capture_origin,
    odometry,
    parameters,
    streams_and_rates,
)
from pymavlink.dialects.v20 import common as M

ACCEPTED, REJECTED = M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_TEMPORARILY_REJECTED
HEARTBEAT_PERIOD_S = (0.94, 1.06)
"""A 1 Hz heartbeat's spacing in vehicle time (ATTITUDE clock: 10 ms steps, link jitter)."""
ACK_AT_ONCE_S = 0.1
"""An ACK 'at once': within this much vehicle time of the command."""
FAILSAFE_DELAY_S = (1.0, 1.3)
"""Offboard loss: the mode changes COM_OF_LOSS_T (1 s) after the last setpoint, plus PX4's
commander period (measured 1.06-1.12 s)."""

pytestmark = pytest.mark.slow  # PX4 and the imitation run as processes in real time

GPS_PEERS = ["imitation-gps", "px4-gps"]
MOCAP_PEERS = ["imitation-mocap", "px4-mocap"]
FIGURES: dict[str, dict] = {}


@pytest.fixture(scope="module")
def peer(request):
    """The peer of the test's parameter, started once; the previous one is stopped first
    (one module-scoped fixture: pytest groups the tests by peer)."""
    name, navigation = request.param.split("-")
    if name == "px4":
        started: Peer = Px4Peer(navigation, request.getfixturevalue("px4_build"))
    else:
        started = ImitationPeer(navigation)
    started.start()
    failed = False
    try:
        yield started
    except BaseException:
        failed = True
        raise
    finally:
        started.stop(failed=failed)


@pytest.fixture(scope="module", autouse=True)
def keep_figures():
    """Write what the scenarios measured to ``$PX4_CONFORMANCE_FIGURES`` at the end."""
    yield
    path = os.environ.get("PX4_CONFORMANCE_FIGURES")
    if path:
        Path(path).write_text(json.dumps(FIGURES, indent=1, default=str))


def record(peer: Peer, scenario: str, figures: dict) -> dict:
    FIGURES.setdefault(f"{peer.name}-{peer.navigation}", {})[scenario] = figures
    return figures


def differs(peer: Peer, what: str) -> bool:
    """This peer documents that it differs from PX4 in ``what``."""
    return what in peer.differences


# ------------------------------------------------------------------ GPS peers


@pytest.mark.parametrize("peer", GPS_PEERS, indirect=True)
def test_default_onboard_streams_and_rates_in_vehicle_time(peer):
    got = record(peer, "streams", streams_and_rates(peer))
    span = got["span_s"]
    for kind, px4_rate in PX4_ONBOARD_RATES_HZ.items():
        rate, interval = got["rates_hz"][kind], got["intervals_us"][kind]
        if differs(peer, kind):
            assert kind in NOT_IMITATED and rate == 0.0 and interval == -1, kind
            continue
        assert abs(rate - px4_rate) <= max(0.1 * px4_rate, 1.5 / span), (kind, rate)
        assert interval == round(1e6 / px4_rate), (kind, interval)


@pytest.mark.parametrize("peer", GPS_PEERS, indirect=True)
def test_odometry_is_px4s_estimate_at_the_estimators_rate(peer):
    got = record(peer, "odometry", odometry(peer))
    assert (got["frame_id"], got["child_frame_id"]) == (M.MAV_FRAME_LOCAL_NED,) * 2
    assert (got["estimator_type"], got["quality"]) == (M.MAV_ESTIMATOR_TYPE_AUTOPILOT, 0)
    assert got["pose_covariance_nonzero"] == [0, 6, 11, 15, 18, 20]
    assert got["velocity_covariance_nonzero"] == [0, 6, 11]
    var_n, var_e, var_d = got["position_variance"]
    assert 0.01 < var_n < 0.2 and var_e == pytest.approx(var_n, rel=0.1) and var_d < var_n
    assert got["reset_counter"] > 0
    expected = {250.0: (125.0, 4000), 50.0: (50.0, 20_000), 10.0: (10.0, 100_000),
                0.0: (30.0, 33_333)}  # fmt: skip
    for asked, (rate, interval) in expected.items():
        run = got["asked"][asked]
        assert run["result"] == ACCEPTED, asked
        assert run["rate_hz"] == pytest.approx(rate, rel=0.06), asked
        assert run["on_imu_grid"], asked  # time_usec: the IMU sample time
        assert run["interval_us"] == interval, asked
        steps = dict(run["steps_us"])
        on_grid = sum(n for step, n in steps.items() if step % 8000 == 0)
        assert on_grid >= 0.95 * sum(steps.values()), (asked, steps)  # the 125 Hz grid
    steps_250 = dict(got["asked"][250.0]["steps_us"])
    assert max(steps_250, key=steps_250.get) == 8000


@pytest.mark.parametrize("peer", GPS_PEERS, indirect=True)
def test_heartbeat_is_1_hz_and_shows_a_mode_change_in_the_next_one(peer):
    got = record(peer, "heartbeat", heartbeat_around_a_mode_change(peer))
    assert all(HEARTBEAT_PERIOD_S[0] <= dt <= HEARTBEAT_PERIOD_S[1] for dt in got["intervals_s"])
    assert [result for _, result in got["acks"]] == [ACCEPTED, ACCEPTED]
    assert got["ack_delay_s"] < ACK_AT_ONCE_S
    # no early heartbeat: the next one keeps the 1 Hz schedule and shows the new mode
    lo, hi = HEARTBEAT_PERIOD_S
    assert lo <= got["next_heartbeat_after_previous_s"] <= hi
    assert got["next_heartbeat_mode"] == LAND


@pytest.mark.parametrize("peer", GPS_PEERS, indirect=True)
def test_command_results(peer):
    got = record(peer, "commands", commands(peer))
    assert got["DO_SET_SERVO"] == M.MAV_RESULT_UNSUPPORTED
    assert got["user command 31000"] == M.MAV_RESULT_UNSUPPORTED
    assert got["SET_MESSAGE_INTERVAL unknown id"] == M.MAV_RESULT_FAILED
    assert got["SET_MESSAGE_INTERVAL HEARTBEAT"] == M.MAV_RESULT_FAILED
    assert got["GET_MESSAGE_INTERVAL ATTITUDE"] == 10_000
    assert got["GET_MESSAGE_INTERVAL unknown id"] == -1
    assert got["REQUEST_MESSAGE unknown id"] == M.MAV_RESULT_DENIED
    assert got["REQUEST_MESSAGE AUTOPILOT_VERSION"] == ACCEPTED
    needed = (
        M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
        | M.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
        | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
        | M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    )
    assert got["capabilities"] & needed == needed
    assert got["flight_sw_version"] >> 16 == (1 << 8) | 17  # v1.17
    assert got["REQUEST_MESSAGE HOME_POSITION"] == ACCEPTED and got["home_position_sent"]
    assert [r for _, r in got["DO_SET_MODE main mode 42"]] == [ACCEPTED, REJECTED]
    assert got["mode after main mode 42"] == LOITER


@pytest.mark.parametrize("peer", GPS_PEERS, indirect=True)
def test_parameter_semantics_and_px4_main_defaults(peer):
    got = record(peer, "parameters", parameters(peer))
    values = got["values"]
    for name, px4_value in PX4_DEFAULTS.items():
        assert values[name] == pytest.approx(px4_value, abs=1e-6), name
    assert values["THR_MDL_FAC"] == pytest.approx(peer.thr_mdl_fac)
    assert values["MAV_TYPE"] == peer.mav_type == got["heartbeat type"]
    assert values["MAV_SIGN_CFG"] is None  # no MAVLink signing parameter in this build
    assert got["by_index"] == ("MPC_THR_HOVER", pytest.approx(0.5))
    assert got["MPC_THR_HOVER type"] == M.MAV_PARAM_TYPE_REAL32
    assert got["COM_OBL_RC_ACT type"] == M.MAV_PARAM_TYPE_INT32
    assert all(values[name] == int(values[name]) for name in INT32_PARAMS if name in values)
    assert got["COM_OBL_RC_ACT wire is bytewise"]
    echo = got["PARAM_SET echo"]
    assert echo and all(v == pytest.approx(3.0) for _, v in echo)
    assert got["PARAM_SET wrong type echo"] == 0 and got["COM_OBL_RC_ACT after wrong type"] == 0
    assert got["unknown read"] is False and got["unknown set echo"] == 0


@pytest.mark.slow
@pytest.mark.parametrize("peer", GPS_PEERS, indirect=True)
def test_flight_takeoff_offboard_thrust_failsafes_return_and_disarm(peer):
    got = record(peer, "flight", flight(peer))
    assert got["arm in Hold"] == ACCEPTED and got["takeoff"] == ACCEPTED
    assert got["takeoff to Hold s"] is not None
    assert got["landed states to Hold"] == [
        M.MAV_LANDED_STATE_ON_GROUND,
        M.MAV_LANDED_STATE_TAKEOFF,
        M.MAV_LANDED_STATE_IN_AIR,
    ]
    # MIS_TAKEOFF_ALT 2.5 m, as the GPS and baro estimate has it some seconds later: PX4's
    # wanders (1.5, 2.7 and 3.8 m in three runs), so this only says the climb was metres
    assert 1.0 <= got["height above home m"] <= 4.5
    # the hover thrust estimator has replaced MPC_THR_HOVER 0.5 with the vehicle's hover thrust
    assert got["Hold thrust setpoint"] == pytest.approx(peer.hover_thrust, abs=0.04)
    # OFFBOARD handshake: refused without setpoints (ACCEPTED, then the refusal)...
    assert [r for _, r in got["OFFBOARD without setpoints"]] == [ACCEPTED, REJECTED]
    assert got["mode after refusal"] == LOITER
    # ...accepted at once with them; the 1 Hz heartbeat shows it when its turn comes
    acks = got["OFFBOARD with setpoints"]
    assert [r for _, r in acks] == [ACCEPTED, ACCEPTED] and acks[-1][0] / 1e3 < ACK_AT_ONCE_S
    lo, hi = HEARTBEAT_PERIOD_S
    assert lo <= got["OFFBOARD heartbeat after previous s"] <= hi
    assert got["OFFBOARD heartbeat mode"] == OFFBOARD
    # relative thrust m g / T_max, level, holds altitude
    assert abs(got["OFFBOARD vertical acceleration m/s2"]) < 0.3
    # ...because PX4 linearizes it with THR_MDL_FAC: a wrong value, set live, shows at once
    predicted = got["wrong THR_MDL_FAC predicted m/s2"]
    assert abs(predicted) > 1.5
    assert got["wrong THR_MDL_FAC measured m/s2"] == pytest.approx(predicted, rel=0.35)
    # offboard loss: COM_OBL_RC_ACT 5 -> Hold after COM_OF_LOSS_T, the intention stays
    changes = got["loss with Hold action"]
    assert changes[0][1] == OFFBOARD and changes[1][1:] == (LOITER, OFFBOARD)
    assert FAILSAFE_DELAY_S[0] <= changes[1][0] <= FAILSAFE_DELAY_S[1]
    assert got["failsafe heartbeat state"] == M.MAV_STATE_CRITICAL
    assert got["stream back"][-1][1] == OFFBOARD and got["stream back"][-1][0] < 0.3
    # the default action (Position) needs RC: Return, home, land, disarm
    changes = got["loss with default action"]
    assert changes[1][1:] == (RTL, OFFBOARD)
    assert FAILSAFE_DELAY_S[0] <= changes[1][0] <= FAILSAFE_DELAY_S[1]
    landed = got["landed states in Return"]
    assert M.MAV_LANDED_STATE_ON_GROUND in landed
    if not differs(peer, "Return height"):
        assert M.MAV_LANDED_STATE_LANDING in landed
    assert 1.5 <= got["disarm after landing s"] <= 4.0  # COM_DISARM_LAND 2 s
    # Home as PX4's estimate has it; on GPS that estimate wanders, most of all on the ground
    # before the disarm (0.5 -> 0.9 m there in one run). PX4 came back from 3.8-10.3 m, where
    # the open-loop OFFBOARD hover had drifted, and landed 0.09-0.94 m from home in 14 runs
    # (mean 0.45 m), 1.001 m in one CI run: 1 m bounded the wander, not PX4.
    assert got["landed from home m"] < 2.0


# ---------------------------------------------------------- motion capture


@pytest.mark.slow
@pytest.mark.parametrize("peer", MOCAP_PEERS, indirect=True)
def test_motion_capture_needs_a_global_origin_to_hold(peer):
    got = record(peer, "motion capture", motion_capture_origin(peer))
    assert got["before origin: streams"] == []
    assert got["before origin: heartbeat state"] == M.MAV_STATE_UNINIT
    assert got["before origin: arm in Hold"] == REJECTED
    assert got["before origin: forced arm in Hold"] == REJECTED  # PX4 checks MAVLink arms
    assert got["before origin: REQUEST_MESSAGE HOME_POSITION"] == M.MAV_RESULT_DENIED
    assert got["before origin: estimator flags"] == 431  # EKF2 on vision alone
    assert got["before origin: horizontal accuracy m"] < 0.02  # millimetres
    assert got["origin echo"] == (473_977_420, 85_455_940, 488_000)
    assert got["home after origin s"] < 3.0 and got["global position after origin"]
    # the estimator resets and settles: 'horizontal position unstable' for about 4 s
    assert got["after origin: reset counter"] == got["before origin: reset counter"] + 3
    assert 2.0 <= got["ready to arm after origin s"] <= 8.0
    assert got["after origin: estimator flags"] == 447  # + POS_HORIZ_ABS
    assert got["after origin: arm in Hold"] == ACCEPTED
    # COM_DISARM_PRFLT 3 s, set live, after COM_SPOOLUP_TIME 1 s: the 1 Hz heartbeat shows
    # the disarm 4-5 s after the arm
    assert got["COM_DISARM_PRFLT echo"] and got["auto-disarm after arming s"] is not None
    assert 3.9 <= got["auto-disarm after arming s"] <= 5.1

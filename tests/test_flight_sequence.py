"""companion.mission.sequence: each stage's transition, cycle by cycle, without links."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from companion.link.px4_modes import px4_mode
from companion.link.telemetry import VehicleStatus
from companion.mission.failsafe import REACTIONS, Fault, FaultEvent
from companion.mission.offboard import Stream
from companion.mission.sequence import (
    WAIT,
    AwaitLink,
    CheckServos,
    FlightSequence,
    Landed,
    Note,
    Observation,
    OffboardLost,
    Px4Request,
    Request,
    SequenceFailed,
    SequenceTimes,
    Stage,
    StartMission,
    StreamTo,
)

TIMES = SequenceTimes(
    cruise_altitude_m=1.5,
    settle_climb_rate_m_s=0.1,
    settle_s=1.0,
    handover_stream_s=0.5,
    takeoff_timeout_s=30.0,
    land_timeout_s=60.0,
)
GROUND_Z_M = 0.1


def heartbeat(mode: str, armed: bool = True) -> VehicleStatus:
    return VehicleStatus(1000, armed, px4_mode(mode), 4 if armed else 3)


def sees(t_s: float, **fields) -> Observation:
    base = dict(ready=True, altitude_m=GROUND_Z_M, climb_rate_m_s=0.0)
    return Observation(t_s, **(base | fields))


def commands(sequence: FlightSequence, obs: Observation) -> list[object]:
    """Everything the sequence asks before it waits for a cycle or an acknowledgement."""
    out = []
    while True:
        command = sequence.next(obs)
        if command is WAIT:
            return out
        out.append(command)
        if isinstance(command, Px4Request | AwaitLink):
            return out


def new(unreachable: str | None = None) -> FlightSequence:
    return FlightSequence(TIMES, lambda ground_z_m, height_offset_m: unreachable)


def taking_off() -> FlightSequence:
    """A sequence whose take-off PX4 acknowledged at t = 0."""
    s = new()
    s.begin()
    assert commands(s, sees(0.0))[-1] == Px4Request(Request.ARM)
    for request in (Request.TAKEOFF_ALTITUDE, Request.TAKEOFF):
        s.done(sees(0.0))
        assert commands(s, sees(0.0))[-1].request == request
    s.done(sees(0.0))
    assert commands(s, sees(0.0)) == [Note("mode", "take-off")]
    return s


def test_the_servo_check_comes_before_arming_and_the_arming_waits_for_it():
    s = FlightSequence(TIMES, lambda ground_z_m, height_offset_m: None, check_servos=True)
    s.begin()
    assert commands(s, sees(0.0))[-1:] == [CheckServos()]
    assert s.stage == Stage.SERVOS
    assert commands(s, sees(5.0)) == []
    out = commands(s, sees(9.0, servos_checked=True))
    assert out[-1] == Px4Request(Request.ARM) and s.stage == Stage.ARM


def test_a_servo_check_that_never_ends_fails_before_arming():
    s = FlightSequence(TIMES, lambda ground_z_m, height_offset_m: None, check_servos=True)
    s.begin()
    commands(s, sees(0.0))
    assert commands(s, sees(30.0)) == []
    with pytest.raises(SequenceFailed, match="servo check did not end within 30 s"):
        s.next(sees(30.1))


def test_heights_above_the_ground_move_by_where_the_ground_lies_in_px4s_frame():
    """With the standing height known, the mission's heights are above the ground: on GPS
    EKF2's origin is the standing vehicle (z = 0), the ground 0.25 m below it, so a 1.5 m
    cruise is 1.25 m up in PX4's frame and the take-off climbs 1.25 m."""
    asked: list[tuple[float, float]] = []
    times = replace(TIMES, standing_height_m=0.25)
    s = FlightSequence(times, lambda z_m, dz_m: asked.append((z_m, dz_m)))
    s.begin()
    out = commands(s, sees(0.6, altitude_m=0.0))
    assert out[0] == Note(
        "preflight",
        "heights above the ground, which lies at z = -0.25 m in PX4's local frame (0.25 m "
        "below the standing vehicle)",
    )
    assert out[-1] == Px4Request(Request.ARM) and asked == [(0.0, -0.25)]
    assert s.height_offset_m == pytest.approx(-0.25)
    s.done(sees(0.7, altitude_m=0.0))
    (altitude,) = commands(s, sees(0.7, altitude_m=0.0))
    assert altitude.value == pytest.approx(1.25)
    # Without it the heights are PX4's own: nothing moves, and the log says so.
    plain = new()
    plain.begin()
    assert commands(plain, sees(0.6, altitude_m=0.0))[0] == Note(
        "preflight", "heights are PX4's local Z ([flight] standing_height_m is not set)"
    )
    assert plain.height_offset_m == 0.0


UP = dict(altitude_m=1.45, heartbeat=heartbeat("LOITER"))
"""At cruise altitude in PX4's Hold."""


def airborne(t_s: float = 10.0) -> tuple[FlightSequence, float]:
    """A sequence taken to the mission stage; returns it and the vehicle time."""
    s = taking_off()
    up = UP
    assert commands(s, sees(t_s, **up)) == []
    assert s.stage == Stage.SETTLE
    assert commands(s, sees(t_s + 1.0, **up)) == [StreamTo(Stream.HOLD)]
    assert commands(s, sees(t_s + 1.5, **up)) == [Px4Request(Request.OFFBOARD)]
    s.done(sees(t_s + 1.6, **up))
    start = commands(s, sees(t_s + 1.6, **up))
    assert start[0] == StartMission() and s.stage == Stage.MISSION
    return s, t_s + 1.6


def test_the_pickup_from_the_ground_to_the_disarm():
    s = new()
    s.begin()
    assert commands(s, Observation(math.nan)) == []  # before the first cycle
    assert commands(s, sees(0.5, ready=False)) == []
    arming = commands(s, sees(0.6))
    assert arming == [
        Note("preflight", "heights are PX4's local Z ([flight] standing_height_m is not set)"),
        Note("mode", "arming (standing at z = 0.10 m)"),
        Px4Request(Request.ARM),
    ]
    assert s.ground_z_m == GROUND_Z_M
    s.done(sees(0.7))
    (altitude,) = commands(s, sees(0.7))
    assert altitude.request == Request.TAKEOFF_ALTITUDE
    assert altitude.value == pytest.approx(1.4)  # above home, not the local frame's origin
    s.done(sees(0.8))
    assert commands(s, sees(0.8)) == [Px4Request(Request.TAKEOFF)]
    s.done(sees(0.9))
    assert commands(s, sees(0.9)) == [Note("mode", "take-off")]
    # Climbed 90 % but PX4 still in TAKEOFF: wait; in LOITER: settle.
    assert commands(s, sees(5.0, altitude_m=1.4, heartbeat=heartbeat("TAKEOFF"))) == []
    assert s.stage == Stage.TAKE_OFF
    up = dict(altitude_m=1.4, heartbeat=heartbeat("LOITER"))
    assert commands(s, sees(5.1, **up)) == [] and s.stage == Stage.SETTLE
    assert commands(s, sees(6.0, **up)) == []
    assert commands(s, sees(6.1, **up)) == [StreamTo(Stream.HOLD)]
    assert commands(s, sees(6.5, **up)) == []
    assert commands(s, sees(6.6, **up)) == [Px4Request(Request.OFFBOARD)]
    s.done(sees(6.7, **up))
    assert commands(s, sees(6.7, **up)) == [
        StartMission(),
        Note("mode", "OFFBOARD accepted: the control loop flies the vehicle"),
    ]
    assert commands(s, sees(30.0, **up)) == []
    assert commands(s, sees(60.0, mission_done=True, **up)) == [
        Px4Request(Request.LAND, stream=Stream.LEVEL)
    ]
    acknowledged = heartbeat("LAND")
    s.done(sees(60.1, heartbeat=acknowledged))
    assert commands(s, sees(60.1, heartbeat=acknowledged)) == [Note("mode", "landing")]
    assert commands(s, sees(70.0, heartbeat=heartbeat("LAND"))) == []  # still armed
    assert not s.finished
    assert commands(s, sees(71.0, heartbeat=heartbeat("LAND", armed=False))) == [
        Landed(),
        Note("mode", "disarmed"),
    ]
    assert s.finished


def test_no_state_estimate_within_2_s_fails():
    s = new()
    s.begin()
    assert commands(s, sees(1.0, ready=False)) == []
    assert commands(s, sees(3.0, ready=False)) == []
    with pytest.raises(SequenceFailed, match="no state estimate within 2 s"):
        commands(s, sees(3.1, ready=False))


def test_a_cruise_altitude_too_close_to_the_ground_or_an_unreachable_plan_fails_unarmed():
    s = new()
    s.begin()
    with pytest.raises(SequenceFailed, match=r"less than 0.5 m above .*z = 1.20 m"):
        commands(s, sees(0.0, altitude_m=1.2))
    s = new("the object lies below the ground")
    s.begin()
    with pytest.raises(SequenceFailed, match="the object lies below the ground"):
        commands(s, sees(0.0))


@pytest.mark.parametrize("refused", [Request.ARM, Request.TAKEOFF_ALTITUDE, Request.TAKEOFF])
def test_any_refusal_on_the_way_up_is_the_take_offs(refused):
    s = new()
    s.begin()
    command = commands(s, sees(0.0))[-1]
    while command.request != refused:
        s.done(sees(0.0))
        (command,) = commands(s, sees(0.0))
    s.done(sees(0.0), "DENIED")
    with pytest.raises(SequenceFailed, match="take-off refused: DENIED"):
        commands(s, sees(0.0))


def test_take_off_and_settling_have_their_limits():
    s = taking_off()
    assert commands(s, sees(30.0, altitude_m=0.5)) == []
    with pytest.raises(
        SequenceFailed, match="take-off did not reach the cruise altitude within 30"
    ):
        commands(s, sees(30.1, altitude_m=0.5))
    s = taking_off()
    commands(s, sees(5.0, **UP))
    # A climb rate above the limit restarts the hold; 20 s without it is a failure.
    for k in range(1, 200):
        rate = 0.2 if k % 9 == 0 else 0.0
        assert commands(s, sees(5.0 + 0.1 * k, climb_rate_m_s=rate, **UP)) == []
    with pytest.raises(SequenceFailed, match="did not stop climbing after take-off within 20 s"):
        commands(s, sees(25.1, climb_rate_m_s=0.2, **UP))


def test_offboard_refused_stops_the_stream_then_fails():
    s = taking_off()
    commands(s, sees(5.0, **UP))
    commands(s, sees(6.0, **UP))
    assert commands(s, sees(6.5, **UP)) == [Px4Request(Request.OFFBOARD)]
    s.done(sees(6.6, **UP), "TEMPORARILY_REJECTED")
    assert s.next(sees(6.6, **UP)) == StreamTo(Stream.OFF)
    with pytest.raises(SequenceFailed, match="PX4 refused OFFBOARD: TEMPORARILY_REJECTED"):
        s.next(sees(6.6, **UP))


def test_px4_leaving_offboard_is_the_offboard_lost_fault_and_the_end():
    s, t_s = airborne()
    assert commands(s, sees(t_s + 5.0, left_offboard=True, heartbeat=heartbeat("POSCTL"))) == [
        OffboardLost("PX4 left OFFBOARD (now POSCTL)")
    ]
    assert s.finished


def test_the_land_waits_for_a_heartbeat_newer_than_its_acknowledgement():
    s = new()
    s.land(Stream.LEVEL, 1.0)
    assert commands(s, sees(1.0)) == [Px4Request(Request.LAND, stream=Stream.LEVEL)]
    stale = heartbeat("LOITER", armed=False)  # from before the arming
    s.done(sees(1.1, heartbeat=stale))
    assert commands(s, sees(1.1, heartbeat=stale)) == [Note("mode", "landing")]
    assert commands(s, sees(61.1, heartbeat=stale)) == []
    with pytest.raises(SequenceFailed, match="did not land and disarm within 60 s"):
        commands(s, sees(61.2, heartbeat=stale))


def test_a_refused_land_fails():
    s = new()
    s.land(Stream.GROUND, 1.0)
    assert commands(s, sees(1.0)) == [Px4Request(Request.LAND, stream=Stream.GROUND)]
    s.done(sees(1.1), "DENIED")
    with pytest.raises(SequenceFailed, match="PX4 refused to land: DENIED"):
        commands(s, sees(1.1))


def fault(kind: Fault) -> FaultEvent:
    return FaultEvent(20.0, kind, "detail", REACTIONS[kind])


def test_offboard_lost_gives_the_vehicle_to_px4():
    s, t_s = airborne()
    s.react(fault(Fault.OFFBOARD_LOST), False, t_s)
    assert commands(s, sees(t_s)) == [StreamTo(Stream.OFF)]
    assert s.finished


def test_saturation_holds_2_s_in_px4s_hold_then_lands_level():
    s, t_s = airborne()
    s.react(fault(Fault.SATURATION), False, t_s)
    assert commands(s, sees(t_s)) == [Px4Request(Request.HOLD, stream=Stream.LEVEL)]
    s.done(sees(t_s + 0.1))
    assert commands(s, sees(t_s + 2.0)) == []
    assert commands(s, sees(t_s + 2.1)) == [Px4Request(Request.LAND, stream=Stream.LEVEL)]


def test_a_refused_hold_is_noted_and_the_vehicle_lands_at_once():
    s, t_s = airborne()
    s.react(fault(Fault.LOOP_OVERRUN), False, t_s)
    commands(s, sees(t_s))
    s.done(sees(t_s), "DENIED")
    assert commands(s, sees(t_s)) == [
        Note("fault", "PX4 refused to hold: DENIED"),
        Px4Request(Request.LAND, stream=Stream.LEVEL),
    ]


def test_ground_contact_lands_level_at_the_thrust_floor():
    s, t_s = airborne()
    s.react(fault(Fault.GROUND_CONTACT), False, t_s)
    assert commands(s, sees(t_s)) == [Px4Request(Request.LAND, stream=Stream.GROUND)]


def test_a_lost_link_waits_for_its_return_before_the_land():
    s, t_s = airborne()
    s.react(fault(Fault.LINK_LOST), True, t_s)
    assert commands(s, sees(t_s, link_lost=True)) == [StreamTo(Stream.OFF), AwaitLink(60.0)]
    with pytest.raises(RuntimeError, match="still waiting"):
        s.next(sees(t_s))
    s.done(sees(t_s + 5.0))
    assert commands(s, sees(t_s + 5.0)) == [
        Note("link", "regained"),
        Px4Request(Request.LAND, stream=Stream.LEVEL),
    ]
    s, t_s = airborne()
    s.react(fault(Fault.LINK_LOST), True, t_s)
    commands(s, sees(t_s, link_lost=True))
    s.done(sees(t_s + 60.0), "timed out")
    with pytest.raises(SequenceFailed, match="did not return within 60 s"):
        s.next(sees(t_s + 60.0))


def test_a_link_back_before_the_reaction_lands_at_once():
    s, t_s = airborne()
    s.react(fault(Fault.LINK_LOST), True, t_s)
    assert commands(s, sees(t_s)) == [Px4Request(Request.LAND, stream=Stream.LEVEL)]


def test_a_land_after_a_failure_replaces_it():
    s = new()
    s.begin()
    commands(s, sees(0.0))
    s.done(sees(0.0), "DENIED")
    s.land(Stream.LEVEL, 0.0)
    assert commands(s, sees(0.0)) == [Px4Request(Request.LAND, stream=Stream.LEVEL)]


def test_done_without_a_request_is_a_bug():
    with pytest.raises(RuntimeError, match="nothing was awaited"):
        new().done(sees(0.0))


def test_the_height_is_watched_only_up_to_the_handover():
    s = new()
    assert not s.watches_height  # idle
    s.begin()
    assert s.watches_height
    s, _ = airborne()
    assert s.stage == Stage.MISSION and not s.watches_height

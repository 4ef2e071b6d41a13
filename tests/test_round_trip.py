"""The link's round trip in vehicle time: TIMESYNC requests stamped with the newest pose's
time, PX4's replies stamped with its clock, and the ``link_latency`` fault."""

from __future__ import annotations

from itertools import pairwise

import pytest

from companion.mission.failsafe import REACTIONS, Fault, Reaction
from companion.mission.round_trip import RoundTripWatch

MS = 1_000_000  # ns


def test_requests_go_out_every_period_of_vehicle_time_stamped_with_the_pose():
    watch = RoundTripWatch(0.1, period_s=0.05)
    sent = [watch.request(t_us) for t_us in range(1_000_000, 1_200_000, 8_000)]
    stamps = [t for t in sent if t is not None]
    assert stamps[0] == 1_000_000_000
    assert [b - a for a, b in pairwise(stamps)] == [56 * MS] * 3


def test_the_round_trip_is_the_reply_clock_less_the_pose_stamp():
    watch = RoundTripWatch(0.1)
    ts1 = watch.request(2_000_000)
    trip = watch.reply(ts1 + 12 * MS, ts1)
    assert trip is not None and trip.round_trip_s == pytest.approx(0.012)
    assert trip.fault is None
    assert watch.round_trips_s == [pytest.approx(0.012)]


def test_a_reply_to_no_request_of_ours_or_twice_is_not_counted():
    watch = RoundTripWatch(0.1)
    ts1 = watch.request(2_000_000)
    assert watch.reply(ts1 + 900 * MS, ts1 + 1) is None  # another component's request
    assert watch.reply(ts1 + 10 * MS, ts1) is not None
    assert watch.reply(ts1 + 10 * MS, ts1) is None  # the same reply read again
    assert len(watch.round_trips_s) == 1


def late_trips(watch: RoundTripWatch, start_us: int, trips_ms: list[int]):
    out = []
    for i, trip_ms in enumerate(trips_ms):
        ts1 = watch.request(start_us + i * 50_000)
        assert ts1 is not None
        out.append(watch.reply(ts1 + trip_ms * MS, ts1))
    return out


def test_three_late_replies_in_a_row_are_the_fault_and_one_in_time_ends_it():
    watch = RoundTripWatch(0.1, late_replies=3)
    trips = late_trips(watch, 1_000_000, [20, 150, 600, 10, 150, 600, 610, 620])
    faults = [t.fault for t in trips]
    assert faults[:6] == [None] * 6  # two late, one in time, two late
    assert faults[6] is not None and "610 ms over the 100 ms limit in 3 replies" in faults[6]
    assert faults[7] is not None  # still too slow


def test_lost_requests_are_no_alarm():
    watch = RoundTripWatch(0.1)
    for i in range(40):  # every request lost: no reply, no round trip, no fault
        watch.request(1_000_000 + i * 50_000)
    ts1 = watch.request(4_000_000)
    trip = watch.reply(ts1 + 15 * MS, ts1)
    assert trip is not None and trip.fault is None


def test_the_fault_hands_the_vehicle_to_px4s_hold():
    assert REACTIONS[Fault.LINK_LATENCY] == (Reaction.FREEZE_ESTIMATE, Reaction.HOLD_THEN_LAND)


@pytest.mark.parametrize("args", [(0.0,), (0.1, 0.0), (0.1, 0.05, 0)])
def test_bad_limits_are_refused(args):
    with pytest.raises(ValueError):
        RoundTripWatch(*args)

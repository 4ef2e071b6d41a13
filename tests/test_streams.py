"""The onboard link's streams (companion.mission.streams): the streams the companion reads
asked, the others stopped and given back; against the simulated PX4 in lockstep, and
against the real PX4 build (``PX4_SITL_DIR``), which judges both."""

from __future__ import annotations

import asyncio

import pytest
from pymavlink.dialects.v20 import common as M

from bytelink.memory import attach
from companion.link import MavlinkLink, VehiclePose
from companion.mission.streams import (
    BATTERY_RATE_HZ,
    LANDED_RATE_HZ,
    PX4_ONBOARD_STREAMS,
    UNTOUCHED,
    OnboardStreams,
    read_streams,
    stream_name,
    streams_to_stop,
)
from sitl.px4_sitl.launcher import Px4Sitl
from sitl.scenario import load_scenario
from sitl.vehicle.lockstep import run_lockstep
from sitl.vehicle.options import RunOptions
from sitl.vehicle.runner import SitlVehicle

ODOMETRY, ATTITUDE, GPS_RAW_INT = (
    M.MAVLINK_MSG_ID_ODOMETRY,
    M.MAVLINK_MSG_ID_ATTITUDE,
    M.MAVLINK_MSG_ID_GPS_RAW_INT,
)


def test_the_streams_read_follow_the_pose_source():
    assert read_streams("odometry", 125.0) == {
        ODOMETRY: 125.0,
        M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: LANDED_RATE_HZ,
        M.MAVLINK_MSG_ID_SYS_STATUS: BATTERY_RATE_HZ,
    }
    local = read_streams("local_position", 50.0)
    assert local[M.MAVLINK_MSG_ID_LOCAL_POSITION_NED] == 50.0
    assert local[M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION] == 50.0
    assert ODOMETRY not in local
    with pytest.raises(ValueError):
        read_streams("odometry", 0.0)


def test_a_stream_is_stopped_when_px4_says_it_is_on_and_nobody_reads_it():
    read = read_streams("odometry", 125.0)
    intervals = {
        ATTITUDE: 10_000,  # on
        ODOMETRY: 33_333,  # read
        M.MAVLINK_MSG_ID_HEARTBEAT: 1_000_000,  # PX4 refuses its interval
        M.MAVLINK_MSG_ID_MISSION_CURRENT: -1,  # not a stream
        GPS_RAW_INT: -1,  # on every update, seen: on
        M.MAVLINK_MSG_ID_CAMERA_TRIGGER: -1,  # not seen: not sent
        M.MAVLINK_MSG_ID_STATUSTEXT: -1,  # seen, not one of PX4's streams
        M.MAVLINK_MSG_ID_VFR_HUD: None,  # no answer
        M.MAVLINK_MSG_ID_SCALED_IMU: 0,  # PX4: present at interval 0, sends nothing
    }
    seen = {ATTITUDE, GPS_RAW_INT, M.MAVLINK_MSG_ID_STATUSTEXT, ODOMETRY}
    assert streams_to_stop(intervals, seen, read) == [GPS_RAW_INT, ATTITUDE]  # by id


def test_px4s_onboard_streams_are_known_by_id_and_name():
    assert {ATTITUDE, GPS_RAW_INT, 436, 8, 380} <= PX4_ONBOARD_STREAMS
    assert M.MAVLINK_MSG_ID_HEARTBEAT in UNTOUCHED and not UNTOUCHED & set(
        read_streams("odometry", 1)
    )
    assert stream_name(ATTITUDE) == "ATTITUDE" and stream_name(436) == "CURRENT_MODE"
    assert stream_name(380) == "#380"


async def _count(link: MavlinkLink, seconds: float) -> tuple[float, dict[int, int]]:
    """Messages per second of vehicle time (the poses' clock) over about ``seconds``, and
    the rate of each id pymavlink decodes [Hz]."""
    with link.subscribe(VehiclePose) as poses:
        await poses.get()  # counts start at a pose
        first, before = link.latest(VehiclePose), link.messages_from_vehicle()
        unknown = link.stats.unknown_messages
    await asyncio.sleep(seconds)
    with link.subscribe(VehiclePose) as poses:
        await poses.get()
        last, after = link.latest(VehiclePose), link.messages_from_vehicle()
        unknown = link.stats.unknown_messages - unknown
    assert first is not None and last is not None
    span = (last.time_usec - first.time_usec) * 1e-6
    counts = {k: n - before.get(k, 0) for k, n in after.items() if n > before.get(k, 0)}
    total = sum(counts.values()) + unknown  # PX4's events: outside pymavlink's dialect
    return total / span, {k: round(n / span, 1) for k, n in counts.items()}


async def _trim_and_restore(connect: str, notes: list[tuple[str, str]]) -> dict:
    """The streams a mission sets (the pose asked at 250 Hz, as ``companion mission``
    does), counted; then given back. Every stream PX4 may send is asked its interval
    before and after, by the link the companion flies with."""
    async with MavlinkLink(connect) as link:
        await link.wait_vehicle()
        await asyncio.sleep(1.0)  # every default stream seen once at least
        default_rate, default_counts = await _count(link, 3.0)
        ids = sorted((set(default_counts) | PX4_ONBOARD_STREAMS) - {M.MAVLINK_MSG_ID_HEARTBEAT})
        before = {i: await link.get_message_interval(i) for i in ids}
        streams = OnboardStreams(link, lambda kind, text: notes.append((kind, text)))
        await streams.ask(read_streams("odometry", 250.0))
        await streams.stop_unread()
        changed = list(streams.changed)
        await asyncio.sleep(0.5)
        trimmed_rate, trimmed_counts = await _count(link, 5.0)
        await streams.restore()
        after = {i: await link.get_message_interval(i) for i in ids}
        await asyncio.sleep(0.5)
        restored_rate, _ = await _count(link, 3.0)
    return {
        "default": (default_rate, default_counts),
        "trimmed": (trimmed_rate, trimmed_counts),
        "restored": restored_rate,
        "before": before,
        "after": after,
        "changed": changed,
        "stopped": streams.stopped,
    }


def _check(got: dict, notes: list[tuple[str, str]]) -> None:
    assert notes == []
    default_rate, _ = got["default"]
    assert default_rate > 300.0, got["default"]
    rate, per_s = got["trimmed"]
    assert per_s[ODOMETRY] == pytest.approx(125.0, abs=2.0), per_s  # the estimator's rate
    assert per_s[M.MAVLINK_MSG_ID_SYS_STATUS] == pytest.approx(BATTERY_RATE_HZ, abs=1.0)
    assert rate <= 150.0, per_s
    assert set(got["changed"]) <= set(got["before"])
    assert {ATTITUDE, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT} <= set(got["stopped"])
    assert got["after"] == got["before"]
    assert got["restored"] == pytest.approx(default_rate, rel=0.1)


def test_the_imitation_streams_only_what_is_read_then_its_defaults_again():
    scenario = load_scenario("configs/sitl_pickup.toml")
    notes: list[tuple[str, str]] = []
    with SitlVehicle(scenario, RunOptions(memory="streams-test", seed=1)) as vehicle:
        got = run_lockstep(vehicle, _trim_and_restore(vehicle.describe()["connect"], notes))
    _check(got, notes)
    assert set(got["trimmed"][1]) == {ODOMETRY, M.MAVLINK_MSG_ID_SYS_STATUS,
                                      M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
                                      M.MAVLINK_MSG_ID_HEARTBEAT}  # fmt: skip
    assert got["before"][M.MAVLINK_MSG_ID_CAMERA_TRIGGER] == -1  # not a stream here


def test_the_imitation_builds_nothing_for_a_link_no_one_hears():
    scenario = load_scenario("configs/sitl_pickup.toml")
    with SitlVehicle(scenario, RunOptions(memory="unheard-test", seed=1)) as vehicle:
        attach("unheard-test-onboard")  # the companion's link; no one on the GCS link
        for _ in range(500):
            vehicle.step()
        onboard, gcs = vehicle.links["onboard"].counters, vehicle.links["gcs"].counters
    assert onboard["sent"] > 100
    assert gcs["sent"] == 0 and gcs["unheard"] == 0  # not even made to be dropped


def test_px4_streams_only_what_is_read_then_its_defaults_again(px4_build):
    """PX4 SIH (GPS) on its onboard link: about 406 messages/s by default; with the
    mission's streams at most 150 (ODOMETRY at its estimator's 125 Hz, SYS_STATUS 20,
    EXTENDED_SYS_STATE 1, HEARTBEAT and MISSION_CURRENT 1, PX4's events); afterwards every
    stream answers GET_MESSAGE_INTERVAL as before."""
    notes: list[tuple[str, str]] = []
    with Px4Sitl(px4_build) as px4:
        assert px4.ports is not None
        connect = f"udpin://127.0.0.1:{px4.ports.onboard_remote}"
        got = asyncio.run(_trim_and_restore(connect, notes))
    print({k: v for k, v in got.items() if k in ("default", "trimmed", "restored")})
    _check(got, notes)
    assert M.MAVLINK_MSG_ID_GPS_RAW_INT in got["stopped"]  # sent on every update

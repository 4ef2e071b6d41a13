"""The companion relay that brings the companion into PX4's lockstep
(:mod:`sitl.hil.companion_relay`), on loopback sockets standing in for PX4's onboard link
and the companion: what it forwards, when it engages, how long it holds the clock."""

from __future__ import annotations

import socket
import threading
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl.hil.companion_relay import CompanionRelay, mavlink_frames
from sitl.vehicle.launch import free_udp_port

PX4 = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
APP = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)


def odometry(time_usec: int) -> bytes:
    nan9 = [float("nan")] * 21
    return PX4.odometry_encode(
        time_usec, 1, 2, 0.0, 0.0, -1.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0,
        0.0, 0.0, 0.0, nan9, nan9,
    ).pack(PX4)  # fmt: skip


def setpoint(time_boot_ms: int) -> bytes:
    return APP.set_attitude_target_encode(
        time_boot_ms, 1, 1, 7, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0.5
    ).pack(APP)


def position_setpoint(time_boot_ms: int) -> bytes:
    return APP.set_position_target_local_ned_encode(
        time_boot_ms, 1, 1, 1, 2048, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    ).pack(APP)


def heartbeat() -> bytes:
    return APP.heartbeat_encode(18, 8, 0, 0, 0).pack(APP)


class Ends:
    """PX4's onboard link and the companion as two loopback sockets around a relay."""

    def __init__(self, timeout_s: float = 0.5, **faults) -> None:
        self.reads = 0
        local, app_port = free_udp_port(), free_udp_port()
        self.relay = CompanionRelay((local, app_port), lambda: self.reads, timeout_s, **faults)
        self.relay.open()
        px4_local, relay_px4_port = self.relay.px4_ports
        self.px4 = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.px4.bind(("127.0.0.1", px4_local))
        self.px4.settimeout(1.0)
        self.app = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.app.bind(("127.0.0.1", app_port))
        self.app.settimeout(1.0)
        self.to_relay_from_px4 = ("127.0.0.1", relay_px4_port)
        self.to_relay_from_app = ("127.0.0.1", local)

    def px4_sends(self, data: bytes) -> None:
        self.px4.sendto(data, self.to_relay_from_px4)
        time.sleep(0.01)

    def app_sends(self, data: bytes) -> None:
        self.app.sendto(data, self.to_relay_from_app)
        time.sleep(0.01)

    def close(self) -> None:
        self.relay.close()
        self.px4.close()
        self.app.close()


@pytest.fixture
def ends():
    ends = Ends()
    yield ends
    ends.close()


def test_frames_of_a_datagram_are_read_across_noise_and_a_truncated_tail():
    data = odometry(4_000_000) + b"\x00\x17" + setpoint(4000) + heartbeat()[:7]
    frames = list(mavlink_frames(data))
    assert [msgid for msgid, _ in frames] == [331, 82]
    # MAVLink 2 drops the payload's trailing zero bytes; the leading time field is whole.
    assert int.from_bytes(frames[0][1][:8], "little") == 4_000_000
    assert int.from_bytes(frames[1][1][:4], "little") == 4000


def test_bytes_pass_unchanged_both_ways(ends):
    pose = odometry(1_000_000) + heartbeat()
    ends.px4_sends(pose)
    ends.relay.pump()
    assert ends.app.recvfrom(1024)[0] == pose
    answer = setpoint(1000)
    ends.app_sends(answer)
    ends.relay.pump()
    assert ends.px4.recvfrom(1024)[0] == answer
    assert ends.relay.last_pose_ms == 1000 and ends.relay.answered_ms == 1000


def test_a_client_that_does_not_answer_poses_never_holds_the_clock(ends):
    ends.px4_sends(odometry(2_000_000))
    ends.app_sends(setpoint(123_456_789))  # MAVSDK's own clock, not the pose's
    ends.px4_sends(odometry(2_004_000))
    start = time.perf_counter()
    ends.relay.hold()
    assert not ends.relay.engaged and ends.relay.holds == 0
    assert time.perf_counter() - start < 0.1


def test_the_clock_waits_for_the_answer_and_the_joint_read(ends):
    ends.px4_sends(odometry(3_000_000))
    ends.relay.pump()
    ends.app_sends(setpoint(3000))  # answers the pose: engaged
    ends.relay.pump()
    assert ends.relay.engaged
    ends.px4_sends(odometry(3_004_000))

    def companion() -> None:
        time.sleep(0.1)
        ends.app.sendto(setpoint(3004), ends.to_relay_from_app)
        time.sleep(0.1)
        ends.reads += 1  # the Sync Read of the joints for the next cycle

    thread = threading.Thread(target=companion)
    start = time.perf_counter()
    thread.start()
    ends.relay.hold()
    waited = time.perf_counter() - start
    thread.join()
    assert ends.relay.answered_ms == 3004 and ends.relay.releases == 0
    assert ends.relay.holds == 1 and waited >= 0.19 and ends.relay.held_s >= 0.19
    assert ends.px4.recvfrom(1024)[0] == setpoint(3000)  # forwarded while holding
    assert ends.px4.recvfrom(1024)[0] == setpoint(3004)


def test_a_position_target_answers_a_pose_as_an_attitude_setpoint_does(ends):
    """The ``px4_position`` baseline streams SET_POSITION_TARGET_LOCAL_NED, stamped with
    the pose it answers: it engages the hold too (else that companion flies off the lockstep
    and a busy machine makes its cycles late)."""
    ends.px4_sends(odometry(5_000_000))
    ends.relay.pump()
    ends.app_sends(position_setpoint(5000))
    ends.relay.pump()
    assert ends.relay.engaged and ends.relay.answered_ms == 5000
    assert ends.px4.recvfrom(1024)[0] == position_setpoint(5000)


def test_a_companion_that_stops_streaming_releases_the_hold_once(ends):
    ends.px4_sends(odometry(5_000_000))
    ends.relay.pump()
    ends.app_sends(setpoint(5000))
    ends.reads += 1
    ends.relay.hold()
    for t_us in (5_004_000, 5_008_000):  # landed: no more setpoints
        ends.px4_sends(odometry(t_us))
        ends.relay.hold()
    assert ends.relay.releases == 1 and not ends.relay.engaged
    assert 0.45 <= ends.relay.held_s < 1.0  # one answer timeout, then no more waits
    ends.app_sends(setpoint(5008))  # streaming again
    assert ends.relay.answered_ms == 5000  # not yet pumped
    ends.relay.pump()
    assert ends.relay.engaged


def test_a_bad_timeout_is_refused():
    with pytest.raises(ValueError, match="answer_timeout_s"):
        CompanionRelay((free_udp_port(), free_udp_port()), lambda: 0, 0.0)


def test_a_latency_spike_holds_datagrams_back_in_order_until_they_are_due():
    now_s, delay_s = [10.0], [0.3]
    ends = Ends(delay=lambda: delay_s[0], clock=lambda: now_s[0])
    ends.app.settimeout(0.2)
    try:
        first, second = odometry(10_000_000), odometry(10_004_000)
        ends.px4_sends(first)
        ends.relay.pump()
        delay_s[0] = 0.0  # the spike is over, but the link keeps its order
        ends.px4_sends(second)
        ends.relay.pump()
        with pytest.raises(TimeoutError):
            ends.app.recvfrom(1024)
        assert ends.relay.delayed == 2 and ends.relay.last_pose_ms == -1
        now_s[0] = 10.3
        ends.relay.pump()
        assert ends.app.recvfrom(1024)[0] == first
        assert ends.app.recvfrom(1024)[0] == second
        assert ends.relay.last_pose_ms == 10_004
    finally:
        ends.close()
    with pytest.raises(ValueError, match="clock"):
        CompanionRelay((free_udp_port(), free_udp_port()), lambda: 0, 0.5, delay=lambda: 0.1)

"""Motion capture for PX4 SIH (``sitl.px4_sitl.mocap``): the pose math, the feeder against a fake
SIH link, and what the real PX4 does on motion capture without and with a global origin.

The PX4 tests need ``PX4_SITL_DIR`` (skipped otherwise) and fly SIH's vehicle of
``configs/px4_sih_pickup.toml`` through :class:`sitl.px4_sitl.sih_host.SihHost`; they talk to PX4
as the companion does, on the onboard link, with a 1 Hz onboard-controller heartbeat.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from sitl.px4.endpoint import MavlinkEndpoint
from sitl.px4_sitl.launcher import free_instance, release_instance
from sitl.px4_sitl.mocap import (
    DEFAULT_ORIGIN,
    MocapFeeder,
    MocapPose,
    mocap_parameters,
    noisy_pose,
    odometry_message,
    sih_origin,
    truth_pose,
)
from sitl.px4_sitl.sih_host import SihHost
from sitl.scenario import load_scenario

CONFIG = Path(__file__).parent.parent / "configs" / "px4_sih_pickup.toml"
ORIGIN = sih_origin(DEFAULT_ORIGIN)


def _hil_state(north: float, east: float, down: float, q: tuple) -> mavlink.MAVLink_message:
    lat, lon, alt = ORIGIN.global_from_ned(north, east, down)
    return mavlink.MAVLink_hil_state_quaternion_message(
        0, list(q), 0, 0, 0, round(lat * 1e7), round(lon * 1e7), round(alt * 1e3),
        0, 0, 0, 0, 0, 0, 0, 0,
    )  # fmt: skip


def _rotation_vector(q_from: tuple, q_to: tuple) -> np.ndarray:
    """Small rotation [rad] (body axes) taking q_from to q_to: 2 * vec(conj(q_from) q_to)."""
    w1, x1, y1, z1 = q_from
    w2, x2, y2, z2 = q_to
    vec = np.array(
        [
            w1 * x2 - x1 * w2 - y1 * z2 + z1 * y2,
            w1 * y2 + x1 * z2 - y1 * w2 - z1 * x2,
            w1 * z2 - x1 * y2 + y1 * x2 - z1 * w2,
        ]
    )
    w = w1 * w2 + x1 * x2 + y1 * y2 + z1 * z2
    return 2.0 * vec * (1.0 if w >= 0.0 else -1.0)


# ------------------------------------------------------------------------ pose math


def test_truth_pose_recovers_ned_within_the_degE7_quantum():
    half = math.sqrt(0.5)
    pose = truth_pose(_hil_state(3.2, -1.7, -2.5, (-half, 0.0, 0.0, -half)), ORIGIN)
    # 1e-7 deg is 11 mm north and 7.5 mm east here; altitude is in millimetres
    np.testing.assert_allclose(pose.position_ned_m, (3.2, -1.7, -2.5), atol=6e-3)
    # the same rotation, written with w >= 0
    np.testing.assert_allclose(pose.q_ned_frd, (half, 0.0, 0.0, half))


def test_sih_holds_its_origin_in_float32():
    assert ORIGIN.latitude_deg == pytest.approx(47.397742, abs=2e-6)
    assert ORIGIN.latitude_deg != DEFAULT_ORIGIN.latitude_deg
    assert ORIGIN.latitude_deg == float(np.float32(47.397742))


def test_noisy_pose_has_the_mocap_noise_and_is_reproducible():
    truth = MocapPose((1.0, 2.0, -1.0), (math.cos(0.4), 0.0, 0.0, math.sin(0.4)))
    samples = [noisy_pose(truth, np.random.default_rng(7), 1e-3, 2e-3) for _ in range(2)]
    assert samples[0] == samples[1]
    rng = np.random.default_rng(11)
    poses = [noisy_pose(truth, rng, 1e-3, 2e-3) for _ in range(4000)]
    errors = np.array([p.position_ned_m for p in poses]) - truth.position_ned_m
    np.testing.assert_allclose(errors.std(axis=0), 1e-3, rtol=0.08)
    np.testing.assert_allclose(errors.mean(axis=0), 0.0, atol=1e-4)
    rotations = np.array([_rotation_vector(truth.q_ned_frd, p.q_ned_frd) for p in poses])
    np.testing.assert_allclose(rotations.std(axis=0), 2e-3, rtol=0.08)
    assert all(p.q_ned_frd[0] >= 0.0 for p in poses)
    np.testing.assert_allclose([np.linalg.norm(p.q_ned_frd) for p in poses], 1.0)


def test_odometry_is_a_vision_pose_in_local_ned():
    pose = MocapPose((1.0, -2.0, -0.5), (1.0, 0.0, 0.0, 0.0))
    msg = odometry_message(pose, 123_456, 1e-3, 2e-3)
    assert msg.pack(mavlink.MAVLink(None, 1, 197))  # encodes
    assert (msg.frame_id, msg.child_frame_id) == (
        mavlink.MAV_FRAME_LOCAL_NED,
        mavlink.MAV_FRAME_BODY_FRD,
    )
    assert msg.estimator_type == mavlink.MAV_ESTIMATOR_TYPE_VISION  # MOCAP: EKF2 ignores it
    assert (msg.x, msg.y, msg.z, msg.time_usec, msg.quality) == (1.0, -2.0, -0.5, 123_456, 100)
    assert [msg.pose_covariance[i] for i in (0, 6, 11)] == pytest.approx([1e-6] * 3)
    assert [msg.pose_covariance[i] for i in (15, 18, 20)] == pytest.approx([4e-6] * 3)
    assert math.isnan(msg.vx) and math.isnan(msg.velocity_covariance[0])


def test_mocap_parameters_turn_gps_off_and_vision_on():
    params = mocap_parameters(DEFAULT_ORIGIN, speed=2.0)
    assert params["SENS_EN_GPSSIM"] == 0 and params["EKF2_GPS_CTRL"] == 0
    assert params["EKF2_EV_CTRL"] == 11  # horizontal + vertical position, yaw
    assert params["EKF2_HGT_REF"] == 3  # vision
    assert params["EKF2_BARO_CTRL"] == 0 and params["EKF2_RNG_CTRL"] == 0
    assert params["EKF2_EV_DELAY"] == pytest.approx(10.0)  # 5 ms of wall time at 2x
    assert params["SIH_LOC_LAT0"] == DEFAULT_ORIGIN.latitude_deg


# --------------------------------------------------------------- feeder, fake SIH


def test_the_feeder_asks_for_the_rate_and_forwards_noisy_poses():
    ports = free_instance()
    try:
        sih = MavlinkEndpoint(ports.sih_display_local, ports.sih_display_remote, system_id=2)
        px4 = MavlinkEndpoint(0, 0, system_id=2)
        feeder = MocapFeeder(ports, ORIGIN, np.random.default_rng(0), rate_hz=50.0)
        with sih, px4, feeder:
            feeder.connect(px4.local_address[1])
            feeder.start()
            asked, odometry = [], []
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                for msg in sih.receive():
                    if msg.get_type() == "COMMAND_LONG":
                        asked.append(msg)
                        sih.send(mavlink.MAVLink_command_ack_message(msg.command, 0))
                sih.send(_hil_state(1.0, 2.0, -3.0, (1.0, 0.0, 0.0, 0.0)))
                odometry += [m for m in px4.receive() if m.get_type() == "ODOMETRY"]
                time.sleep(0.005)  # truth at ~150 Hz, faster than asked
            truth = feeder.truth()
        assert asked and asked[0].command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
        assert (asked[0].param1, asked[0].param2) == (115, pytest.approx(20_000))  # 50 Hz
        assert feeder.interval_accepted and len(asked) == 1
        assert 30 <= len(odometry) <= 70  # about 50 per second, not every truth sample
        positions = np.array([(m.x, m.y, m.z) for m in odometry])
        np.testing.assert_allclose(positions.mean(axis=0), (1.0, 2.0, -3.0), atol=6e-3)
        assert positions.std(axis=0).min() > 2e-4  # noisy
        np.testing.assert_allclose(truth[1].position_ned_m, (1.0, 2.0, -3.0), atol=6e-3)
    finally:
        release_instance(ports)


# ---------------------------------------------------------------------- real PX4


class Px4Link:
    """The companion's side of PX4's onboard link, as pymavlink sees it; it sends a 1 Hz
    HEARTBEAT of :attr:`heartbeat_type` (the companion's: an onboard controller)."""

    def __init__(self, url: str, system_id: int) -> None:
        self.heartbeat_type = mavlink.MAV_TYPE_ONBOARD_CONTROLLER
        self.conn = mavutil.mavlink_connection(url.replace("udpin://", "udpin:"), source_system=245)
        self.target = system_id
        self.latest: dict[str, object] = {}
        self.texts: list[str] = []
        self.acks: list[tuple[int, int]] = []
        self._heartbeat_at = 0.0

    def pump(self, seconds: float) -> None:
        """Read for ``seconds``, keeping the latest of each message, STATUSTEXT and ACKs,
        with a heartbeat each second."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if time.monotonic() - self._heartbeat_at >= 1.0:
                self.conn.mav.heartbeat_send(self.heartbeat_type, 8, 0, 0, 0)
                self._heartbeat_at = time.monotonic()
            msg = self.conn.recv_match(blocking=True, timeout=0.1)
            if msg is None:
                continue
            kind = msg.get_type()
            self.latest[kind] = msg
            if kind == "STATUSTEXT":
                self.texts.append(msg.text)
            elif kind == "COMMAND_ACK":
                self.acks.append((msg.command, msg.result))

    def until(self, condition, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.pump(0.2)
            if condition():
                return True
        return False

    def command(self, command: int, *params: float, wait_s: float = 1.5) -> list[int]:
        """COMMAND_LONG; the results of every COMMAND_ACK for it within ``wait_s``."""
        self.acks.clear()
        values = [*params, *[0.0] * (7 - len(params))]
        self.conn.mav.command_long_send(self.target, 1, command, 0, *values)
        self.pump(wait_s)
        return [result for cmd, result in self.acks if cmd == command]

    def param_set(self, name: str, value: float) -> None:
        self.conn.mav.param_set_send(self.target, 1, name.encode(), value, 9)  # REAL32
        self.pump(0.3)

    def stream(self, message_id: int, hz: float) -> None:
        self.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, 1e6 / hz, wait_s=0.2)

    def mode(self) -> tuple[int, int, bool]:
        """(main mode, sub mode, armed) of the latest HEARTBEAT."""
        hb = self.latest["HEARTBEAT"]
        armed = bool(hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        return (hb.custom_mode >> 16) & 0xFF, hb.custom_mode >> 24, armed

    def altitude(self) -> float:
        return -self.latest["LOCAL_POSITION_NED"].z


AUTO, TAKEOFF, LOITER, LAND = 4, 2, 3, 6
TAKEOFF_ALT_M = 1.0
NAN = math.nan


@pytest.fixture
def mocap_px4(px4_build, request) -> Iterator[tuple[SihHost, Px4Link]]:
    host = SihHost(load_scenario(CONFIG), px4_build, navigation="mocap", seed=1)
    host.start()
    link = Px4Link(host.ports.connect_url, host.ports.instance + 1)
    try:
        link.stream(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 20)
        link.pump(1.0)
        yield host, link
    finally:
        link.conn.close()
        kept = host.stop(
            keep=getattr(request.node, "rep_call", None) is None or request.node.rep_call.failed
        )
        if kept is not None:
            print(f"PX4's directory kept in {kept}")


def test_ekf2_converges_on_motion_capture_without_gps(mocap_px4):
    host, link = mocap_px4
    errors = []
    for _ in range(20):
        link.pump(0.1)
        estimate, (_, truth) = link.latest["LOCAL_POSITION_NED"], host.feeder.truth()
        errors.append(np.subtract((estimate.x, estimate.y, estimate.z), truth.position_ned_m))
    # within the truth's own 1e-7 deg quantum and EKF2's 10 mm floor
    assert np.abs(errors).max() < 0.02
    assert host.feeder.interval_accepted and host.feeder.poses_sent > 100
    # no GPS: no global position, no origin (asking for it is DENIED), no home
    origin = mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN
    assert link.command(mavlink.MAV_CMD_REQUEST_MESSAGE, origin) == [mavlink.MAV_RESULT_DENIED]
    assert not {"GPS_GLOBAL_ORIGIN", "GLOBAL_POSITION_INT", "HOME_POSITION"} & set(link.latest)
    # PX4 boots in Hold (AUTO.LOITER), which needs a global position: the heartbeat says
    # MAV_STATE_UNINIT, and arming is refused, without a STATUSTEXT for an onboard
    # controller (PX4 sends STATUSTEXT only once it has heard a ground station)
    assert link.mode() == (AUTO, LOITER, False)
    assert link.latest["HEARTBEAT"].system_status == mavlink.MAV_STATE_UNINIT
    rejected = mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    assert link.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == [rejected]
    assert link.texts == []


@pytest.mark.slow
def test_without_a_global_origin_px4_arms_only_in_takeoff_and_stays_there(mocap_px4):
    _, link = mocap_px4
    link.heartbeat_type = mavlink.MAV_TYPE_GCS  # for PX4's STATUSTEXT
    link.param_set("MIS_TAKEOFF_ALT", TAKEOFF_ALT_M)
    # Hold (AUTO.LOITER, PX4's mode after boot) needs a global position: arming refused
    assert link.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == [
        mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    ]
    assert any("Arming denied: Resolve system health failures" in t for t in link.texts)
    # NAV_TAKEOFF disarmed: accepted, the mode becomes AUTO.TAKEOFF, which may arm
    assert link.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, NAN) == [0]
    assert link.until(lambda: link.mode()[:2] == (AUTO, TAKEOFF), 3.0)
    assert link.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == [mavlink.MAV_RESULT_ACCEPTED]
    assert link.until(lambda: link.altitude() > 0.9 * TAKEOFF_ALT_M, 15.0)
    link.pump(3.0)
    # take-off done: PX4 cannot switch to Hold and stays in AUTO.TAKEOFF, holding altitude
    assert link.mode() == (AUTO, TAKEOFF, True)
    assert abs(link.altitude() - TAKEOFF_ALT_M) < 0.2
    results = link.command(mavlink.MAV_CMD_DO_SET_MODE, 1, AUTO, LOITER)
    assert mavlink.MAV_RESULT_TEMPORARILY_REJECTED in results
    link.pump(1.5)
    assert link.mode() == (AUTO, TAKEOFF, True)
    # land works on the local position
    assert link.command(mavlink.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, NAN, NAN, NAN) == [0]
    assert link.until(lambda: not link.mode()[2], 20.0)
    assert any("Landing detected" in t for t in link.texts)
    assert any("Disarmed by landing" in t for t in link.texts)


@pytest.mark.slow
def test_with_a_global_origin_px4_arms_in_hold_and_holds_after_takeoff(mocap_px4):
    _, link = mocap_px4
    link.heartbeat_type = mavlink.MAV_TYPE_GCS  # for PX4's STATUSTEXT
    link.param_set("MIS_TAKEOFF_ALT", TAKEOFF_ALT_M)
    lat, lon, alt = ORIGIN.latitude_deg, ORIGIN.longitude_deg, ORIGIN.altitude_amsl_m
    link.conn.mav.set_gps_global_origin_send(
        link.target, round(lat * 1e7), round(lon * 1e7), round(alt * 1e3), 0
    )
    assert link.until(lambda: "GPS_GLOBAL_ORIGIN" in link.latest, 3.0)
    origin = link.latest["GPS_GLOBAL_ORIGIN"]
    assert (origin.latitude, origin.longitude) == (round(lat * 1e7), round(lon * 1e7))
    assert link.until(lambda: "HOME_POSITION" in link.latest, 5.0)
    assert link.until(lambda: "GLOBAL_POSITION_INT" in link.latest, 3.0)
    # EKF2 moved its origin: its position checks fail for a moment ("Preflight Fail:
    # horizontal position unstable"), then PX4 is in standby, and Hold can arm
    standby = mavlink.MAV_STATE_STANDBY
    assert link.until(lambda: link.latest["HEARTBEAT"].system_status == standby, 10.0)
    assert link.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == [mavlink.MAV_RESULT_ACCEPTED]
    assert link.command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, NAN) == [0]
    assert link.until(lambda: link.altitude() > 0.9 * TAKEOFF_ALT_M, 15.0)
    # take-off done: AUTO.LOITER (Hold), and asking for it again is accepted
    assert link.until(lambda: link.mode() == (AUTO, LOITER, True), 5.0)
    assert link.command(mavlink.MAV_CMD_DO_SET_MODE, 1, AUTO, LOITER)[-1:] == [0]
    assert link.command(mavlink.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, NAN, NAN, NAN) == [0]
    assert link.until(lambda: not link.mode()[2], 20.0)
    assert any("Disarmed by landing" in t for t in link.texts)

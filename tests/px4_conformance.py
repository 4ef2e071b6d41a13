"""MAVLink conformance scenarios: the real PX4 SITL judges the imitation (``sitl run``).

One set of scenarios, two peers (``tests/test_px4_conformance.py`` runs every scenario on
both), so that the imitation cannot drift from PX4 again:

- :class:`ImitationPeer`: ``sitl run`` (:func:`sitl.vehicle.launch.start_sitl`) with
  ``configs/sitl_pickup.toml``;
- :class:`Px4Peer`: PX4 main's SIH hexacopter (:class:`sitl.px4_sitl.Px4Sitl`) with the
  vehicle of ``configs/px4_sih_pickup.toml`` (:func:`sitl.px4_sitl.sih.sih_parameters`); on motion
  capture with SIH's GPS off, EKF2 on vision and a :class:`sitl.px4_sitl.mocap.MocapFeeder`
  sending it SIH's ground truth as the motion-capture pose.

A peer is started in one aiding mode (``gps`` or ``mocap``) and offers a
:class:`Link` on its onboard (API) link: a pymavlink connection with a reader thread that
keeps every message with the vehicle time it arrived at (the last ATTITUDE's
``time_boot_ms``), so that rates and delays are measured in vehicle time (PX4 SIH runs
at about 0.8x real time on this machine, the imitation at 1x).

Each scenario function takes a started peer, drives it like a companion or ground station
would, and returns what it measured (a dict of figures); the test module compares the
figures with PX4's, which are the expectations below, measured on the real build
(v1.17.0-alpha1, SIH hex). Where the imitation must differ, :attr:`Peer.differences`
says why, and the test checks the imitation's own documented behaviour there.
"""

from __future__ import annotations

import math
import os
import struct
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import ClassVar

os.environ.setdefault("MAVLINK20", "1")

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M

from sitl.px4_sitl.launcher import Px4Build, Px4Sitl, free_instance
from sitl.px4_sitl.mocap import DEFAULT_ORIGIN, MocapFeeder, mocap_parameters, sih_origin
from sitl.px4_sitl.sih import sih_parameters
from sitl.scenario import load_scenario
from sitl.vehicle.launch import SitlProcess, free_udp_port, start_sitl

CONFIGS = Path(__file__).parent.parent / "configs"
IMITATION_CONFIG = CONFIGS / "sitl_pickup.toml"
PX4_CONFIG = CONFIGS / "px4_sih_pickup.toml"

CURRENT_MODE = 436
"""CURRENT_MODE (development dialect): PX4 streams the mode flown and the one intended."""

PX4_ONBOARD_RATES_HZ: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 5.0,
    "SYSTEM_TIME": 1.0,
    "PING": 1.0,
    "ATTITUDE": 100.0,
    "ATTITUDE_QUATERNION": 50.0,
    "LOCAL_POSITION_NED": 30.0,
    "GLOBAL_POSITION_INT": 50.0,
    "VFR_HUD": 10.0,
    "ATTITUDE_TARGET": 10.0,
    "HIGHRES_IMU": 50.0,
    "TIMESYNC": 10.0,
    "ALTITUDE": 10.0,
    "BATTERY_STATUS": 0.5,
    "ESTIMATOR_STATUS": 1.0,
    "HOME_POSITION": 0.5,
    "EXTENDED_SYS_STATE": 5.0,
    "ODOMETRY": 30.0,
    "CURRENT_MODE": 0.5,
    "SERVO_OUTPUT_RAW": 10.0,
    "POSITION_TARGET_LOCAL_NED": 10.0,
    "DISTANCE_SENSOR": 10.0,
    "SCALED_PRESSURE": 1.0,
    "VIBRATION": 0.5,
}
"""PX4 main's default onboard-link streams (its GET_MESSAGE_INTERVAL, SIH, GPS)."""

NOT_IMITATED: dict[str, str] = {
    "SERVO_OUTPUT_RAW": "the imitation's mixer runs inside the truth plant, not the autopilot",
    "POSITION_TARGET_LOCAL_NED": "the imitation has no trajectory setpoint generator",
    "DISTANCE_SENSOR": "the airframe has no rangefinder (SIH simulates one)",
    "SCALED_PRESSURE": "raw barometer data: the imitation has no sensor drivers",
    "VIBRATION": "IMU vibration metrics: the imitation has no sensor drivers",
}
"""PX4 streams the imitation does not send, and why."""

PX4_DEFAULTS: dict[str, float] = {
    "MC_ROLL_P": 4.0,
    "MC_PITCH_P": 4.0,
    "MC_YAW_P": 2.8,
    "MC_YAW_WEIGHT": 0.4,
    "MC_ROLLRATE_P": 0.15,
    "MC_ROLLRATE_I": 0.2,
    "MC_ROLLRATE_D": 0.003,
    "MC_ROLLRATE_K": 1.0,
    "MC_ROLLRATE_MAX": 220.0,
    "MPC_THR_HOVER": 0.5,
    "MPC_THR_MIN": 0.12,
    "MPC_THR_MAX": 1.0,
    "COM_OF_LOSS_T": 1.0,
    "COM_OBL_RC_ACT": 0,
    "COM_DISARM_LAND": 2.0,
    "COM_DISARM_PRFLT": 10.0,
    "MIS_TAKEOFF_ALT": 2.5,
    "MPC_TKO_SPEED": 1.5,
    "MPC_LAND_SPEED": 0.7,
    "MC_AIRMODE": 0,
    "MC_BAT_SCALE_EN": 0,
    "CA_AIRFRAME": 0,
    "CA_ROTOR_COUNT": 6,
    "IMU_INTEG_RATE": 250,
    "IMU_GYRO_RATEMAX": 800,
}
"""PX4 main's parameter values on the SIH hex (also the imitation's, from the scenario)."""

INT32_PARAMS = frozenset(
    {"COM_OBL_RC_ACT", "MC_AIRMODE", "MC_BAT_SCALE_EN", "CA_AIRFRAME", "CA_ROTOR_COUNT",
     "IMU_INTEG_RATE", "IMU_GYRO_RATEMAX", "MAV_TYPE"}
)  # fmt: skip

LOITER, OFFBOARD, LAND, RTL = "LOITER", "OFFBOARD", "LAND", "RTL"
_MODE_NUMBERS = {LOITER: (4, 3), OFFBOARD: (6, 0), LAND: (4, 6), RTL: (4, 5)}


def _bytewise(value: int) -> float:
    return struct.unpack("<f", struct.pack("<i", int(value)))[0]


def _int_of(wire: float) -> int:
    return struct.unpack("<i", struct.pack("<f", wire))[0]


def mode_name(custom_mode: int) -> str:
    """PX4's mode name (pymavlink's, e.g. LOITER) of a ``custom_mode``."""
    return mavutil.interpret_px4_mode(M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode)


class Link:
    """The peer's onboard link from the companion's side, recorded in vehicle time.

    Parameters
    ----------
    port
        The UDP port the peer's onboard link sends to (bound here, ``udpin``).
    """

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{port}", source_system=255, source_component=190
        )
        self.system_id = 0
        self.vehicle_ms = 0
        """Vehicle time of the last ATTITUDE received [ms since boot]."""
        self._log: list[tuple[int, object]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._reader = threading.Thread(target=self._read, name="conformance-link", daemon=True)
        self._reader.start()
        self._setpoints: threading.Thread | None = None
        self._setpoint = ([1.0, 0.0, 0.0, 0.0], 0.0)
        self.last_setpoint_ms = 0
        """Vehicle time at which the last streamed setpoint was sent [ms]."""
        self._streaming = threading.Event()

    def close(self) -> None:
        self.stop_setpoints()
        self._stop.set()
        self._reader.join(timeout=2.0)
        self.conn.close()

    def _read(self) -> None:
        while not self._stop.is_set():
            msg = self.conn.recv_match(blocking=True, timeout=0.1)
            if msg is None or msg.get_type() == "BAD_DATA":
                continue
            if msg.get_type() == "ATTITUDE":
                self.vehicle_ms = msg.time_boot_ms
            elif msg.get_type() == "HEARTBEAT" and msg.autopilot == M.MAV_AUTOPILOT_PX4:
                self.system_id = msg.get_srcSystem()
            with self._lock:
                self._log.append((self.vehicle_ms, msg))

    # ------------------------------------------------------------- reading

    def mark(self) -> int:
        """A position in the record: what comes after it is new."""
        with self._lock:
            return len(self._log)

    def since(self, mark: int, kind: str | None = None) -> list[tuple[int, object]]:
        """(vehicle ms at arrival, message) received after ``mark`` (of type ``kind``)."""
        with self._lock:
            log = self._log[mark:]
        return [(t, m) for t, m in log if kind is None or m.get_type() == kind]

    def wait(
        self, kind: str, condition: Callable[[object], bool] = lambda m: True,
        timeout_s: float = 10.0, mark: int | None = None,
    ) -> tuple[int, object] | None:  # fmt: skip
        """The first ``kind`` message after ``mark`` (default: now) meeting ``condition``,
        waiting up to ``timeout_s`` of wall time; None if none came."""
        mark = self.mark() if mark is None else mark
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for entry in self.since(mark, kind):
                if condition(entry[1]):
                    return entry
            time.sleep(0.01)
        return None

    def wait_vehicle_s(self, seconds: float, timeout_s: float = 60.0) -> None:
        """Let ``seconds`` of vehicle time pass."""
        end = self.vehicle_ms + seconds * 1e3
        deadline = time.monotonic() + timeout_s
        while self.vehicle_ms < end and time.monotonic() < deadline:
            time.sleep(0.01)

    def heartbeat(self, timeout_s: float = 3.0) -> tuple[int, object]:
        """The next HEARTBEAT of the autopilot (vehicle ms, message)."""
        entry = self.wait("HEARTBEAT", lambda m: m.autopilot == M.MAV_AUTOPILOT_PX4, timeout_s)
        assert entry is not None, "no heartbeat"
        return entry

    # ------------------------------------------------------------- commands

    def command(self, command: int, *params: float, wait_s: float = 1.0) -> list[tuple[int, int]]:
        """Send COMMAND_LONG; returns [(vehicle ms after sending, result)] of every
        COMMAND_ACK for it within ``wait_s`` of wall time (DO_SET_MODE gets two)."""
        p = [*params, *[0.0] * (7 - len(params))]
        mark, sent = self.mark(), self.vehicle_ms
        self.conn.mav.command_long_send(self.system_id, 1, command, 0, *p)
        first = self.wait("COMMAND_ACK", lambda m: m.command == command, 5.0, mark)
        if first is None:
            return []
        time.sleep(wait_s)
        return [
            (t - sent, m.result) for t, m in self.since(mark, "COMMAND_ACK") if m.command == command
        ]

    def result(self, command: int, *params: float) -> int | None:
        """The result of a command: its last COMMAND_ACK (None: no answer)."""
        acks = self.command(command, *params, wait_s=0.3)
        return acks[-1][1] if acks else None

    def set_mode(self, mode: str) -> list[tuple[int, int]]:
        """DO_SET_MODE to a PX4 mode name; its ACKs as :meth:`command`."""
        main, sub = _MODE_NUMBERS[mode]
        return self.command(M.MAV_CMD_DO_SET_MODE, 1, main, sub, wait_s=0.3)

    def set_interval(self, msg_id: int, rate_hz: float) -> int | None:
        """SET_MESSAGE_INTERVAL at ``rate_hz`` (0: default, -1: off); the result."""
        interval = rate_hz if rate_hz <= 0 else 1e6 / rate_hz
        return self.result(M.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, interval)

    def get_interval(self, msg_id: int) -> int | None:
        """GET_MESSAGE_INTERVAL: the interval PX4 reports [us] (-1: not streamed)."""
        mark = self.mark()
        self.conn.mav.command_long_send(
            self.system_id, 1, M.MAV_CMD_GET_MESSAGE_INTERVAL, 0, msg_id, 0, 0, 0, 0, 0, 0
        )
        entry = self.wait("MESSAGE_INTERVAL", lambda m: m.message_id == msg_id, 3.0, mark)
        return None if entry is None else entry[1].interval_us

    # ----------------------------------------------------------- parameters

    def param_read(self, name: str = "", index: int = -1, wait_s: float = 2.0):
        """PARAM_REQUEST_READ by name or index; the PARAM_VALUE, or None (no answer)."""
        mark = self.mark()
        self.conn.mav.param_request_read_send(self.system_id, 1, name.encode(), index)
        entry = self.wait("PARAM_VALUE", lambda m: not name or m.param_id == name, wait_s, mark)
        return None if entry is None else entry[1]

    def param_set(self, name: str, value: float, kind: int, wait_s: float = 1.0) -> list:
        """PARAM_SET (INT32 sent bytewise when ``kind`` is INT32); the PARAM_VALUE echoes
        of ``name`` on this link within ``wait_s``."""
        wire = _bytewise(int(value)) if kind == M.MAV_PARAM_TYPE_INT32 else float(value)
        mark = self.mark()
        self.conn.mav.param_set_send(self.system_id, 1, name.encode(), wire, kind)
        time.sleep(wait_s)
        return [m for _, m in self.since(mark, "PARAM_VALUE") if m.param_id == name]

    # ------------------------------------------------------------ setpoints

    def start_setpoints(self, thrust: float, rate_hz: float = 50.0) -> None:
        """Stream level SET_ATTITUDE_TARGET (attitude + thrust) at ``rate_hz`` (wall)."""
        self._setpoint = ([1.0, 0.0, 0.0, 0.0], float(thrust))
        if self._setpoints is not None:
            return
        self._streaming.set()

        def stream() -> None:
            while self._streaming.is_set():
                q, thrust = self._setpoint
                self.conn.mav.set_attitude_target_send(
                    0, self.system_id, 1, 0b111, q, 0.0, 0.0, 0.0, thrust
                )
                self.last_setpoint_ms = self.vehicle_ms
                time.sleep(1.0 / rate_hz)

        self._setpoints = threading.Thread(target=stream, name="setpoints", daemon=True)
        self._setpoints.start()

    def stop_setpoints(self) -> int:
        """Stop the stream; returns the vehicle time of the last setpoint sent [ms]."""
        if self._setpoints is not None:
            self._streaming.clear()
            self._setpoints.join(timeout=2.0)
            self._setpoints = None
        return self.last_setpoint_ms


class Peer:
    """A vehicle the scenarios run on; :meth:`start` it, use :attr:`link`, :meth:`stop` it.

    Attributes
    ----------
    name : str
        ``imitation`` or ``px4``.
    navigation : str
        ``gps`` or ``mocap``.
    hover_thrust : float
        Relative thrust that holds the vehicle's weight: m g / (6 T_max) of its truth.
    thr_mdl_fac : float
        THR_MDL_FAC of the airframe (the motors' curve).
    mav_type : int
        MAV_TYPE the airframe reports.
    differences : dict of str to str
        Where this peer must differ from PX4, and why.
    """

    name = "abstract"
    hover_thrust = 0.0
    thr_mdl_fac = 0.0
    mav_type = 0
    differences: ClassVar[dict[str, str]] = {}

    def __init__(self, navigation: str) -> None:
        self.navigation = navigation
        self.link: Link | None = None

    def start(self) -> None:
        raise NotImplementedError

    def stop(self, failed: bool = False) -> None:
        raise NotImplementedError


class ImitationPeer(Peer):
    """``sitl run`` with ``configs/sitl_pickup.toml``."""

    name = "imitation"
    mav_type = M.MAV_TYPE_HEXAROTOR
    differences: ClassVar[dict[str, str]] = {
        **NOT_IMITATED,
        "MAV_TYPE": "a configured hexacopter airframe (PX4's 6001_hexa_x sets 13); PX4's SIH "
        "hex airframe leaves the multicopter default 2",
        "THR_MDL_FAC": "the airframe's motors have the scenario's curve (0.3); SIH's are linear",
        "Return height": "NOT YET IMITATED: at the offboard loss with the default action the "
        "imitation's vehicle is 0.1-0.2 m above home (it sinks in the wrong-THR_MDL_FAC "
        "step, and its Hold returns to where the failsafe struck) where PX4 SIH's is about "
        "7 m up and 10 m away (it climbs on the test's fixed thrust, and PX4's Hold brakes "
        "and stops): its Return lands at once, and the landing state shows LANDING or not "
        "as the EXTENDED_SYS_STATE samples fall",
    }

    def __init__(self, navigation: str) -> None:
        super().__init__(navigation)
        scenario = load_scenario(IMITATION_CONFIG)
        arm = scenario.arm
        mass = scenario.vehicle.mass_kg + arm.link1.mass_kg + arm.link2.mass_kg
        rotors = scenario.vehicle.rotors
        self.hover_thrust = (
            mass * scenario.environment.gravity_m_s2 / (6 * rotors.max_thrust_per_rotor_n)
        )
        self.thr_mdl_fac = rotors.thr_mdl_fac
        self.process: SitlProcess | None = None

    def start(self) -> None:
        # PX4 SIH's thrust ignores the battery (its own simulator is held full): the
        # imitation it is held against flies without the scenario's [plant.battery] too
        text = IMITATION_CONFIG.read_text()
        start = text.index("\n[plant.battery]")
        end = text.index("\n[", start + 1)
        self._config_dir = tempfile.TemporaryDirectory()
        config = Path(self._config_dir.name) / IMITATION_CONFIG.name
        config.write_text(text[:start] + text[end:])
        self.process = start_sitl(config, "--navigation", self.navigation, "--seed", "1", speed=1.0)
        self.link = Link(self.process.onboard_port)
        self.link.heartbeat(timeout_s=20.0)

    def stop(self, failed: bool = False) -> None:
        if self.link is not None:
            self.link.close()
        if self.process is not None:
            self.process.stop()


class Px4Peer(Peer):
    """PX4 main's SIH hex with the vehicle of ``configs/px4_sih_pickup.toml``."""

    name = "px4"
    mav_type = M.MAV_TYPE_QUADROTOR

    def __init__(self, navigation: str, build: Px4Build) -> None:
        super().__init__(navigation)
        scenario = load_scenario(PX4_CONFIG)
        self.params = sih_parameters(scenario)
        if navigation == "mocap":
            self.params.update(mocap_parameters(DEFAULT_ORIGIN))
        self.hover_thrust = self.params["SIH_MASS"] * 9.80665 / (6 * self.params["SIH_T_MAX"])
        self.thr_mdl_fac = scenario.vehicle.rotors.thr_mdl_fac
        self.build = build
        self.px4: Px4Sitl | None = None
        self.feeder: MocapFeeder | None = None

    def start(self) -> None:
        """Start PX4; on motion capture (as ``sitl sih`` does) bind the feeder's ports first,
        start a MAVLink link for it in PX4 once the start-up script is done, and wait until
        PX4 is ready for takeoff."""
        ports = free_instance()
        ready = ("Ready for takeoff!",)
        if self.navigation == "mocap":
            self.feeder = MocapFeeder(ports, sih_origin(DEFAULT_ORIGIN), np.random.default_rng(1))
            self.feeder.open()
            ready = ("Startup script returned successfully",)
        self.px4 = Px4Sitl(self.build, params=self.params, ready_lines=ready, ports=ports)
        self.px4.start()
        assert self.px4.ports is not None
        self.link = Link(self.px4.ports.onboard_remote)
        if self.feeder is not None:
            port = free_udp_port()
            self.px4.command(
                "mavlink", "start", "-u", str(port), "-o", str(self.feeder.local_port),
                "-m", "minimal", "-r", "200000",
            )  # fmt: skip
            self.feeder.connect(port)
            self.feeder.start()
            self.px4.wait_for_log(("Ready for takeoff!",), 60.0)
        self.link.heartbeat(timeout_s=20.0)

    def stop(self, failed: bool = False) -> None:
        if self.link is not None:
            self.link.close()
        if self.feeder is not None:
            self.feeder.close()
        if self.px4 is not None:
            self.px4.stop(keep=failed)


# ---------------------------------------------------------------- scenarios


def streams_and_rates(peer: Peer, seconds: float = 5.0) -> dict:
    """Default onboard streams, before any request: the rate of each in vehicle time
    [Hz] over ``seconds`` of vehicle time, and the interval GET_MESSAGE_INTERVAL reports
    for it [us] (-1: not streamed)."""
    link = peer.link
    assert link is not None
    link.wait_vehicle_s(0.5)
    start_ms, mark = link.vehicle_ms, link.mark()
    link.wait_vehicle_s(seconds)
    end_ms = link.vehicle_ms
    counts = Counter(m.get_type() for t, m in link.since(mark) if start_ms < t <= end_ms)
    span_s = (end_ms - start_ms) / 1e3
    rates = {kind: counts.get(kind, 0) / span_s for kind in PX4_ONBOARD_RATES_HZ}
    intervals = {}
    for kind in PX4_ONBOARD_RATES_HZ:
        msg_id = CURRENT_MODE if kind == "CURRENT_MODE" else getattr(M, f"MAVLINK_MSG_ID_{kind}")
        intervals[kind] = link.get_interval(msg_id)
    return {"span_s": span_s, "rates_hz": rates, "intervals_us": intervals}


def odometry(peer: Peer) -> dict:
    """ODOMETRY: its fields at the default rate, then the rate and the spacing of
    ``time_usec`` when 250, 50 and 10 Hz are asked (and the interval PX4 then reports)."""
    link = peer.link
    assert link is not None
    odo_id = M.MAVLINK_MSG_ID_ODOMETRY
    mark = link.mark()
    link.wait_vehicle_s(1.0)
    sample = link.since(mark, "ODOMETRY")[-1][1]
    out: dict = {
        "frame_id": sample.frame_id,
        "child_frame_id": sample.child_frame_id,
        "estimator_type": sample.estimator_type,
        "quality": sample.quality,
        "reset_counter": sample.reset_counter,
        "pose_covariance_nonzero": [i for i, v in enumerate(sample.pose_covariance) if v != 0],
        "velocity_covariance_nonzero": [
            i for i, v in enumerate(sample.velocity_covariance) if v != 0
        ],
        "position_variance": [sample.pose_covariance[i] for i in (0, 6, 11)],
        "velocity_variance": [sample.velocity_covariance[i] for i in (0, 6, 11)],
        "attitude_variance": [sample.pose_covariance[i] for i in (15, 18, 20)],
        "asked": {},
    }
    for rate in (250.0, 50.0, 10.0, 0.0):
        result = link.set_interval(odo_id, rate)
        link.wait_vehicle_s(0.3)
        mark = link.mark()
        link.wait_vehicle_s(2.0)
        stamps = [m.time_usec for _, m in link.since(mark, "ODOMETRY")]
        steps = np.diff(stamps)
        out["asked"][rate] = {
            "result": result,
            "rate_hz": (len(stamps) - 1) / ((stamps[-1] - stamps[0]) * 1e-6),
            "steps_us": sorted(Counter(steps.tolist()).items()),
            "on_imu_grid": all(s % 4000 == 0 for s in stamps),
            "interval_us": link.get_interval(odo_id),
        }
    return out


def heartbeat_around_a_mode_change(peer: Peer) -> dict:
    """HEARTBEAT spacing in vehicle time, and a mode change (disarmed, Hold -> Land): when
    its ACKs come and which heartbeat first shows the new mode."""
    link = peer.link
    assert link is not None
    link.heartbeat()
    mark = link.mark()
    link.wait_vehicle_s(3.2)
    before = [t for t, m in link.since(mark, "HEARTBEAT")]
    previous_ms, _ = link.heartbeat()
    link.wait_vehicle_s(0.3)
    sent_ms, mark = link.vehicle_ms, link.mark()
    acks = link.set_mode(LAND)
    beats = [
        (t, mode_name(m.custom_mode))
        for t, m in link.since(mark, "HEARTBEAT")
        if m.autopilot == M.MAV_AUTOPILOT_PX4
    ]
    while not beats:
        t, m = link.heartbeat()
        beats.append((t, mode_name(m.custom_mode)))
    link.set_mode(LOITER)
    return {
        "intervals_s": (np.diff(before) / 1e3).tolist(),
        "acks": acks,
        "ack_delay_s": acks[-1][0] / 1e3 if acks else None,
        "next_heartbeat_after_previous_s": (beats[0][0] - previous_ms) / 1e3,
        "next_heartbeat_after_command_s": (beats[0][0] - sent_ms) / 1e3,
        "next_heartbeat_mode": beats[0][1],
    }


def commands(peer: Peer) -> dict:
    """Command results: unsupported commands, message intervals, requested messages and
    mode numbers PX4 does not know."""
    link = peer.link
    assert link is not None
    out: dict = {
        "DO_SET_SERVO": link.result(M.MAV_CMD_DO_SET_SERVO, 1, 1500),
        "user command 31000": link.result(31000),
        "SET_MESSAGE_INTERVAL unknown id": link.result(M.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1e5),
        "SET_MESSAGE_INTERVAL HEARTBEAT": link.result(
            M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HEARTBEAT, 1e5
        ),
        "GET_MESSAGE_INTERVAL ATTITUDE": link.get_interval(M.MAVLINK_MSG_ID_ATTITUDE),
        "GET_MESSAGE_INTERVAL unknown id": link.get_interval(9999),
        "REQUEST_MESSAGE unknown id": link.result(M.MAV_CMD_REQUEST_MESSAGE, 9999),
    }
    mark = link.mark()
    out["REQUEST_MESSAGE AUTOPILOT_VERSION"] = link.result(
        M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION
    )
    version = link.wait("AUTOPILOT_VERSION", timeout_s=2.0, mark=mark)
    out["capabilities"] = None if version is None else version[1].capabilities
    out["flight_sw_version"] = None if version is None else version[1].flight_sw_version
    mark = link.mark()
    out["REQUEST_MESSAGE HOME_POSITION"] = link.result(
        M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION
    )
    out["home_position_sent"] = link.wait("HOME_POSITION", timeout_s=2.0, mark=mark) is not None
    out["DO_SET_MODE main mode 42"] = link.command(M.MAV_CMD_DO_SET_MODE, 1, 42, 0, wait_s=0.3)
    out["mode after main mode 42"] = mode_name(link.heartbeat()[1].custom_mode)
    return out


def parameters(peer: Peer) -> dict:
    """Parameter semantics: read by name and by index, INT32 bytewise, PARAM_SET echo, a
    PARAM_SET of the wrong type, unknown names; the values PX4 main has."""
    link = peer.link
    assert link is not None
    values = {}
    for name in [*PX4_DEFAULTS, "MAV_TYPE", "THR_MDL_FAC", "MAV_SIGN_CFG"]:
        value = link.param_read(name, wait_s=1.0)
        if value is None:
            values[name] = None
        elif value.param_type == M.MAV_PARAM_TYPE_INT32:
            values[name] = _int_of(value.param_value)
        else:
            values[name] = round(value.param_value, 6)
    hover = link.param_read("MPC_THR_HOVER")
    by_index = link.param_read(index=hover.param_index)
    obl = link.param_read("COM_OBL_RC_ACT")
    echo = link.param_set("MIS_TAKEOFF_ALT", 3.0, M.MAV_PARAM_TYPE_REAL32)
    link.param_set("MIS_TAKEOFF_ALT", 2.5, M.MAV_PARAM_TYPE_REAL32, wait_s=0.3)
    wrong_type = link.param_set("COM_OBL_RC_ACT", 4.0, M.MAV_PARAM_TYPE_REAL32)
    after_wrong = _int_of(link.param_read("COM_OBL_RC_ACT").param_value)
    heartbeat = link.heartbeat()[1]
    return {
        "values": values,
        "count": hover.param_count,
        "by_index": (by_index.param_id, by_index.param_value) if by_index else None,
        "MPC_THR_HOVER type": hover.param_type,
        "COM_OBL_RC_ACT type": obl.param_type,
        "COM_OBL_RC_ACT wire is bytewise": obl.param_value == _bytewise(0),
        "PARAM_SET echo": [(m.param_id, m.param_value) for m in echo],
        "PARAM_SET wrong type echo": len(wrong_type),
        "COM_OBL_RC_ACT after wrong type": after_wrong,
        "unknown read": link.param_read("NO_SUCH_PARAM", wait_s=1.0) is not None,
        "unknown set echo": len(link.param_set("NO_SUCH_PARAM", 1.0, M.MAV_PARAM_TYPE_REAL32)),
        "heartbeat type": heartbeat.type,
    }


def _curve(u: float, f: float) -> float:
    """PX4's thrust curve: relative thrust of motor command u with THR_MDL_FAC f."""
    return f * u * u + (1.0 - f) * u


def _inverse_curve(relative: float, f: float) -> float:
    """The motor command PX4 sends for a relative thrust with THR_MDL_FAC f."""
    if f == 0.0:
        return relative
    return (math.sqrt((1.0 - f) ** 2 + 4.0 * f * relative) - (1.0 - f)) / (2.0 * f)


def _vertical_acceleration(link: Link, mark: int) -> float:
    """Slope of the estimated climb rate (LOCAL_POSITION_NED) since ``mark`` [m/s^2, up]."""
    samples = [(m.time_boot_ms / 1e3, -m.vz) for _, m in link.since(mark, "LOCAL_POSITION_NED")]
    t, vz = np.array(samples).T
    return float(np.polyfit(t - t[0], vz, 1)[0])


def _mode_changes(link: Link, mark: int, since_ms: int) -> list[tuple[float, str, str]]:
    """(vehicle s after ``since_ms``, mode flown, mode intended) at each change of
    CURRENT_MODE after ``mark``."""
    out: list[tuple[float, str, str]] = []
    for t, m in link.since(mark, "CURRENT_MODE"):
        entry = ((t - since_ms) / 1e3, mode_name(m.custom_mode), mode_name(m.intended_custom_mode))
        if not out or out[-1][1:] != entry[1:]:
            out.append(entry)
    return out


def flight(peer: Peer) -> dict:
    """One flight (GPS): arm, take off to MIS_TAKEOFF_ALT, hold (the hover thrust
    estimate), the OFFBOARD handshake, relative thrust in OFFBOARD and THR_MDL_FAC set live,
    offboard loss with COM_OBL_RC_ACT 5 (Hold) and back, offboard loss with the default
    (Return), the landing and the auto-disarm."""
    link = peer.link
    assert link is not None
    out: dict = {}
    link.set_interval(CURRENT_MODE, 50.0)
    link.set_interval(M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE, 20.0)
    mark = link.mark()
    out["arm in Hold"] = link.result(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    takeoff_ms = link.vehicle_ms
    out["takeoff"] = link.result(M.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7)
    link.wait("CURRENT_MODE", lambda m: mode_name(m.custom_mode) != LOITER, 5.0)
    held = link.wait("CURRENT_MODE", lambda m: mode_name(m.custom_mode) == LOITER, 40.0)
    out["takeoff to Hold s"] = None if held is None else (held[0] - takeoff_ms) / 1e3
    out["takeoff thrust (s, thrust)"] = [
        (round((t - takeoff_ms) / 1e3, 1), round(m.thrust, 3))
        for t, m in link.since(mark, "ATTITUDE_TARGET")[::5]
        if t <= (held[0] if held else t)
    ]
    link.wait_vehicle_s(6.0)  # the hover thrust estimator converges in a few seconds
    home = link.since(0, "HOME_POSITION")[-1][1]
    local = link.since(mark, "LOCAL_POSITION_NED")[-1][1]
    out["height above home m"] = home.z - local.z
    thrusts = [m.thrust for t, m in link.since(mark, "ATTITUDE_TARGET")][-10:]
    out["Hold thrust setpoint"] = float(np.mean(thrusts))
    states = [m.landed_state for _, m in link.since(mark, "EXTENDED_SYS_STATE")]
    out["landed states to Hold"] = [s for i, s in enumerate(states) if i == 0 or states[i - 1] != s]

    # The OFFBOARD handshake.
    out["OFFBOARD without setpoints"] = link.set_mode(OFFBOARD)
    out["mode after refusal"] = mode_name(link.heartbeat()[1].custom_mode)
    link.start_setpoints(peer.hover_thrust)
    link.wait_vehicle_s(0.5)
    before_ms, _ = link.heartbeat()
    link.wait_vehicle_s(0.3)
    sent_ms, mark = link.vehicle_ms, link.mark()
    out["OFFBOARD with setpoints"] = link.set_mode(OFFBOARD)
    beat_ms, beat = link.heartbeat()
    out["OFFBOARD heartbeat after previous s"] = (beat_ms - before_ms) / 1e3
    out["OFFBOARD heartbeat after command s"] = (beat_ms - sent_ms) / 1e3
    out["OFFBOARD heartbeat mode"] = mode_name(beat.custom_mode)

    # Relative thrust m g / T_max, level: the vertical acceleration in OFFBOARD.
    link.wait_vehicle_s(0.5)
    mark = link.mark()
    link.wait_vehicle_s(3.0)
    out["OFFBOARD vertical acceleration m/s2"] = _vertical_acceleration(link, mark)

    # THR_MDL_FAC set live to a curve the motors do not have: PX4 linearizes with it, so
    # the same relative thrust makes another force. Predicted: g (T / T_hover - 1).
    wrong = 0.3 if peer.thr_mdl_fac == 0.0 else 0.0
    u = _inverse_curve(peer.hover_thrust, wrong)
    made = _curve(u, peer.thr_mdl_fac)
    out["wrong THR_MDL_FAC predicted m/s2"] = 9.81 * (made / peer.hover_thrust - 1.0)
    link.param_set("THR_MDL_FAC", wrong, M.MAV_PARAM_TYPE_REAL32, wait_s=0.0)
    link.wait_vehicle_s(0.3)
    mark = link.mark()
    link.wait_vehicle_s(0.8)
    out["wrong THR_MDL_FAC measured m/s2"] = _vertical_acceleration(link, mark)
    link.param_set("THR_MDL_FAC", peer.thr_mdl_fac, M.MAV_PARAM_TYPE_REAL32, wait_s=0.0)
    link.wait_vehicle_s(1.0)

    # Offboard loss, COM_OBL_RC_ACT 5 (Hold), then the stream comes back.
    link.param_set("COM_OBL_RC_ACT", 5, M.MAV_PARAM_TYPE_INT32, wait_s=0.2)
    mark = link.mark()
    last_ms = link.stop_setpoints()
    link.wait_vehicle_s(2.0)
    out["loss with Hold action"] = _mode_changes(link, mark, last_ms)
    out["failsafe heartbeat state"] = link.heartbeat()[1].system_status
    mark, back_ms = link.mark(), link.vehicle_ms
    link.start_setpoints(peer.hover_thrust)
    link.wait_vehicle_s(1.0)
    out["stream back"] = _mode_changes(link, mark, back_ms)

    # Offboard loss with the default action: Return, landing at home, auto-disarm.
    link.param_set("COM_OBL_RC_ACT", 0, M.MAV_PARAM_TYPE_INT32, wait_s=0.2)
    mark = link.mark()
    last_ms = link.stop_setpoints()
    disarmed = link.wait(
        "HEARTBEAT", lambda m: not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, 60.0, mark
    )
    out["loss with default action"] = _mode_changes(link, mark, last_ms)[:3]
    states = [(t, m.landed_state) for t, m in link.since(mark, "EXTENDED_SYS_STATE")]
    on_ground = next((t for t, s in states if s == M.MAV_LANDED_STATE_ON_GROUND), None)
    out["landed states in Return"] = sorted({s for _, s in states})
    out["disarm after landing s"] = (
        None if disarmed is None or on_ground is None else (disarmed[0] - on_ground) / 1e3
    )
    track = link.since(mark, "LOCAL_POSITION_NED")
    final = track[-1][1]
    out["landed from home m"] = math.hypot(final.x - home.x, final.y - home.y)
    out["Return track (s, from home m, above home m)"] = [
        (round((t - last_ms) / 1e3, 1), round(math.hypot(m.x - home.x, m.y - home.y), 2),
         round(home.z - m.z, 2))
        for t, m in track[:: max(1, len(track) // 12)]
    ]  # fmt: skip
    return out


def motion_capture_origin(peer: Peer) -> dict:
    """Motion capture (no GPS): no global position, Hold refused for arming (forced too);
    SET_GPS_GLOBAL_ORIGIN brings GPS_GLOBAL_ORIGIN, HOME_POSITION and GLOBAL_POSITION_INT,
    then Hold arms; COM_DISARM_PRFLT set live disarms a vehicle that does not take off."""
    link = peer.link
    assert link is not None
    out: dict = {}
    mark = link.mark()
    link.wait_vehicle_s(2.0)
    seen = {m.get_type() for _, m in link.since(mark)}
    out["before origin: streams"] = sorted(
        seen & {"GLOBAL_POSITION_INT", "HOME_POSITION", "GPS_GLOBAL_ORIGIN"}
    )
    out["before origin: heartbeat state"] = link.heartbeat()[1].system_status
    out["before origin: arm in Hold"] = link.result(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    out["before origin: forced arm in Hold"] = link.result(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196)
    out["before origin: REQUEST_MESSAGE HOME_POSITION"] = link.result(
        M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION
    )
    status = link.since(mark, "ESTIMATOR_STATUS")[-1][1]
    out["before origin: estimator flags"] = status.flags
    out["before origin: horizontal accuracy m"] = status.pos_horiz_accuracy
    out["before origin: reset counter"] = link.since(mark, "ODOMETRY")[-1][1].reset_counter
    mark, sent_ms = link.mark(), link.vehicle_ms
    link.conn.mav.set_gps_global_origin_send(link.system_id, 473_977_420, 85_455_940, 488_000)
    origin = link.wait("GPS_GLOBAL_ORIGIN", timeout_s=5.0, mark=mark)
    out["origin echo"] = (
        None if origin is None else (origin[1].latitude, origin[1].longitude, origin[1].altitude)
    )
    home = link.wait("HOME_POSITION", timeout_s=10.0, mark=mark)
    out["home after origin s"] = None if home is None else (home[0] - sent_ms) / 1e3
    out["global position after origin"] = (
        link.wait("GLOBAL_POSITION_INT", timeout_s=5.0, mark=mark) is not None
    )
    ready = link.wait("HEARTBEAT", lambda m: m.system_status == M.MAV_STATE_STANDBY, 30.0, mark)
    out["ready to arm after origin s"] = None if ready is None else (ready[0] - sent_ms) / 1e3
    link.wait_vehicle_s(1.0)
    status = link.since(mark, "ESTIMATOR_STATUS")[-1][1]
    out["after origin: estimator flags"] = status.flags
    out["after origin: reset counter"] = link.since(mark, "ODOMETRY")[-1][1].reset_counter
    out["COM_DISARM_PRFLT echo"] = [
        m.param_value
        for m in link.param_set("COM_DISARM_PRFLT", 3.0, M.MAV_PARAM_TYPE_REAL32, wait_s=0.2)
    ]
    mark, armed_ms = link.mark(), link.vehicle_ms
    out["after origin: arm in Hold"] = link.result(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    link.wait_vehicle_s(6.0)
    beats = [
        ((t - armed_ms) / 1e3, bool(m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED))
        for t, m in link.since(mark, "HEARTBEAT")
        if m.autopilot == M.MAV_AUTOPILOT_PX4
    ]
    out["heartbeats after arming (s, armed)"] = beats
    out["auto-disarm after arming s"] = next((t for t, armed in beats if not armed), None)
    return out

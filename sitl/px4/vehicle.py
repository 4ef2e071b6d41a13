"""The simulated PX4 as seen over MAVLink: messages in, replies, setpoints and telemetry out.

Pure: no sockets, no clock, no asyncio. The runner drives it with simulation time:
``handle()`` every decoded incoming message, ``control()`` and ``telemetry()`` at the plant
steps where they may do something (every step, or only before
:attr:`Px4Vehicle.control_held_until_s` and at :attr:`Px4Vehicle.next_telemetry_us` or a new
estimate: the steps between change nothing); each returns what goes out, as ``(link,
message)``.
What PX4 would print to its console (arming refused, failsafe, ...) is drained with
:meth:`Px4Vehicle.console`: PX4 main reports these as events, not STATUSTEXT (measured on
the real build: no STATUSTEXT on either link).

Message handling follows PX4's ``mavlink_receiver.cpp`` and commander as measured:

- COMMAND_LONG / COMMAND_INT addressed to this system (and to component 1 or 0) are
  answered with COMMAND_ACK on the link they came from at once, ``target_system`` /
  ``target_component`` set to the sender; commands for other systems or components are
  dropped and counted. Unhandled commands: UNSUPPORTED.
- DO_SET_MODE (and the SET_MODE message, ACKed as command 176): see
  :mod:`sitl.px4.commander` for what is accepted; a base mode without the custom-mode
  flag, mode numbers PX4 does not know and AUTO.READY are TEMPORARILY_REJECTED (measured).
  PX4 acknowledges a DO_SET_MODE command twice, at once: ACCEPTED, then the result (a
  refused mode: ACCEPTED then TEMPORARILY_REJECTED); the SET_MODE message once.
- SET_MESSAGE_INTERVAL: ACCEPTED for every message this vehicle can stream, FAILED for
  others and for HEARTBEAT; GET_MESSAGE_INTERVAL answers MESSAGE_INTERVAL (-1: not
  streamed); REQUEST_MESSAGE sends the message once, DENIED when there is no such message
  or no data for it (no global origin, no home).
- SET_ATTITUDE_TARGET that does not ignore attitude is proof of life; setpoints with a
  non-finite or zero quaternion or a thrust outside [0, 1] are dropped and counted. A
  setpoint that ignores thrust has thrust 0, as in PX4. Body-rate setpoints (attitude
  ignored) are not supported by the simulated attitude loop: dropped and counted.
- SET_POSITION_TARGET_LOCAL_NED in MAV_FRAME_LOCAL_NED with position and yaw (velocity and
  acceleration optional: feed-forward) is proof of life; in OFFBOARD the position
  controller flies it with the hover thrust estimator (:mod:`sitl.px4.position_control`).
  Other frames, a target without a position or a yaw, a force setpoint or a value that is
  not finite are dropped and counted (PX4 flies velocity-only and body-frame targets too;
  this imitation does not).
- SET_GPS_GLOBAL_ORIGIN (motion capture): the estimator takes the origin, answers with
  GPS_GLOBAL_ORIGIN on every link, and from then on has a global position and a home.
  With GPS aiding the origin is GPS's and the message is ignored.
- PARAM_REQUEST_LIST / _READ / PARAM_SET per :mod:`sitl.px4.params`: an unknown name or
  index gets no answer; a PARAM_SET whose type is not the parameter's is ignored; a value
  stored is echoed as PARAM_VALUE on every link.
- TIMESYNC requests are answered with the simulation time in nanoseconds.
- A PING request (target 0/0; MAVSDK sends them to measure latency) is returned to its
  sender with the same time and sequence, the target set to the sender, as PX4 does.
"""

from __future__ import annotations

import math
import operator
from collections import Counter
from collections.abc import Collection, Mapping
from typing import ClassVar

from pymavlink.dialects.v20 import common as mavlink

from companion.frames import (
    enu_from_ned,
    euler_enu_flu_from_ned_frd,
    quaternion_enu_flu_from_ned_frd,
)
from sitl.physics import AttitudeSetpoint
from sitl.px4.commander import FORCE_MAGIC, Commander, ConsoleLine
from sitl.px4.geo import GeoReference
from sitl.px4.measurement import VehicleMeasurement
from sitl.px4.modes import Px4Mode
from sitl.px4.params import PARAMETERS, ParamError, Px4Params, UnknownParamError
from sitl.px4.position_control import PositionTarget
from sitl.px4.streams import GCS_RATES_HZ, ONBOARD_RATES_HZ, StreamScheduler
from sitl.px4.telemetry import Home, TelemetryEncoder, VehicleStatus

__all__ = ["FLIGHT_SW_VERSION", "Outgoing", "Px4Vehicle"]

M = mavlink
Outgoing = list[tuple[str, mavlink.MAVLink_message]]

FLIGHT_SW_VERSION = (1 << 24) | (17 << 16) | (0 << 8) | M.FIRMWARE_VERSION_TYPE_ALPHA
"""AUTOPILOT_VERSION.flight_sw_version: PX4 v1.17.0 alpha, as the real build (v1.17.0-alpha1)
reports it (PX4's byte layout: major, minor, patch, type)."""

_BROADCAST_TARGET_COMMANDS = (M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,)
_RELATIVE_FRAMES = (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)


def _finite_int(value: float) -> int | None:
    return round(value) if math.isfinite(value) else None


class Px4Vehicle:
    """The PX4 side of the simulated vehicle; see the module docstring.

    Parameters
    ----------
    params : Px4Params
        Parameter values (shared with the commander; PARAM_SET changes them).
    system_id, component_id : int
        MAVLink ids of the autopilot (PX4: MAV_SYS_ID, 1).
    link_rates_hz : mapping of link name to {message id: rate [Hz]}, optional
        The links and their default stream rates; default ``{"onboard":
        ONBOARD_RATES_HZ, "gcs": GCS_RATES_HZ}``.
    geo : GeoReference, optional
        Geodetic position of the world origin (PX4 SITL's default home): the global
        origin with GPS aiding, the AMSL reference of the baro in any case.
    gravity_m_s2 : float
        Gravity used by the position controller [m/s^2].
    aiding : {"vision", "gps"}
        The estimator's position aiding: with GPS it has a global position from boot,
        with vision (motion capture) only after SET_GPS_GLOBAL_ORIGIN.
    unix_time_at_boot_us : int
        Wall-clock time at boot [us since 1970] (SYSTEM_TIME).
    """

    def __init__(
        self,
        params: Px4Params,
        *,
        system_id: int = 1,
        component_id: int = 1,
        link_rates_hz: Mapping[str, Mapping[int, float]] | None = None,
        geo: GeoReference | None = None,
        gravity_m_s2: float = 9.80665,
        aiding: str = "vision",
        unix_time_at_boot_us: int = 0,
    ) -> None:
        if aiding not in ("vision", "gps"):
            raise ValueError(f"aiding must be 'vision' or 'gps', got {aiding!r}")
        self.params = params
        self.system_id = int(system_id)
        self.component_id = int(component_id)
        self.aiding = aiding
        rates = link_rates_hz or {"onboard": ONBOARD_RATES_HZ, "gcs": GCS_RATES_HZ}
        streamable = TelemetryEncoder.streamable()
        self._schedulers = {link: StreamScheduler(r, streamable) for link, r in rates.items()}
        self.geo = geo or GeoReference()
        self._encoder = TelemetryEncoder(self.geo, FLIGHT_SW_VERSION, unix_time_at_boot_us)
        origin = self.geo if aiding == "gps" else None
        self._commander = Commander(params, gravity_m_s2, global_origin=origin)
        self._origin_pending = origin is not None
        self._last: VehicleMeasurement | None = None
        self._last_estimate_us: int | None = None
        self._held_until_s = -math.inf
        self.counters: Counter[str] = Counter()
        """Dropped or ignored input by reason (e.g. ``invalid_setpoint``, ``not_for_us``)."""

    # ---------------------------------------------------------------- state

    @property
    def links(self) -> list[str]:
        """Link names, as given in ``link_rates_hz``."""
        return list(self._schedulers)

    @property
    def mode(self) -> Px4Mode:
        """The mode flown."""
        return self._commander.mode

    @property
    def intended_mode(self) -> Px4Mode:
        """The mode the user asked for (differs from :attr:`mode` in a failsafe)."""
        return self._commander.user_mode

    @property
    def armed(self) -> bool:
        """Motors armed."""
        return self._commander.armed

    @property
    def landed(self) -> bool:
        """The land detector's verdict at the last step."""
        return self._commander.landed

    @property
    def landed_state(self) -> int:
        """MAV_LANDED_STATE_* as reported in EXTENDED_SYS_STATE."""
        return self._commander.landed_state

    @property
    def failsafe(self) -> bool:
        """A failsafe flies another mode than the one asked for."""
        return self._commander.failsafe

    @property
    def home(self) -> Home | None:
        """Home position (world ENU), None without a global position."""
        return self._commander.home

    @property
    def global_origin(self) -> GeoReference | None:
        """The estimator's global origin (None: no global position)."""
        return self._commander.origin

    @property
    def hover_thrust(self) -> float:
        """The relative hover thrust the position controller flies with [-]."""
        return self._commander.hover_thrust

    def offboard_alive(self, now_s: float) -> bool:
        """The offboard setpoint stream is fresher than COM_OF_LOSS_T at ``now_s`` [s]."""
        return self._commander.offboard_alive(now_s)

    @property
    def console_waiting(self) -> bool:
        """:meth:`console` has lines to give."""
        return bool(self._commander.console)

    def console(self) -> list[ConsoleLine]:
        """The console lines since the last call (PX4 prints these to its log)."""
        lines = list(self._commander.console)
        self._commander.console.clear()
        return lines

    # ----------------------------------------------------------- time steps

    def control(self, now_s: float, m: VehicleMeasurement) -> AttitudeSetpoint | None:
        """Run the state machine at ``now_s`` [s] and return the attitude setpoint for this
        plant step (body FLU -> world ENU, relative thrust), or None while disarmed."""
        self._last = m
        commander = self._commander
        before = commander.decisions()
        commander.update(now_s, m)
        setpoint = commander.setpoint(now_s, m)
        after = commander.decisions()
        settled = len(before) == len(after) and all(map(operator.is_, before, after))
        self._held_until_s = commander.next_deadline_s(now_s) if settled else -math.inf
        return setpoint

    @property
    def control_held_until_s(self) -> float:
        """Simulation time [s] before which :meth:`control` with the same measurement, and
        no message handled since the last call, returns the same setpoint and decides
        nothing: the last call decided nothing, and no deadline of the commander falls
        before it (-inf after a call that decided something, or a message)."""
        return self._held_until_s

    @property
    def next_telemetry_us(self) -> int:
        """Simulation time [us] before which :meth:`telemetry` with the same estimate
        returns nothing and changes nothing (0 while a new global origin waits to go out)."""
        if self._origin_pending and self._commander.origin is not None:
            return 0
        return min(scheduler.next_due_us for scheduler in self._schedulers.values())

    def telemetry(
        self, now_s: float, m: VehicleMeasurement, unheard: Collection[str] = ()
    ) -> Outgoing:
        """Every stream message due at ``now_s`` [s] on each link (streams of the estimate
        only when ``m`` is a new estimate), and GPS_GLOBAL_ORIGIN when the origin is new.

        Nothing is built for the links in ``unheard`` (no one listens on them): their
        streams stay on their schedule, so that a listener who comes later gets them on
        the same grid, but their messages are neither made nor returned.
        """
        self._last = m
        now_us = round(now_s * 1e6)
        fresh = m.estimate_time_us != self._last_estimate_us
        self._last_estimate_us = m.estimate_time_us
        status: VehicleStatus | None = None
        built: dict[int, mavlink.MAVLink_message | None] = {}
        out: Outgoing = []
        for link, scheduler in self._schedulers.items():
            due = scheduler.due(now_us, fresh)
            if link in unheard:
                continue
            for msg_id in due:
                if msg_id not in built:
                    if status is None:
                        status = self._status()
                    built[msg_id] = self._encoder.build(msg_id, now_s, m, status)
                message = built[msg_id]
                if message is not None:
                    out.append((link, message))
        if self._origin_pending and self._commander.origin is not None:
            self._origin_pending = False
            origin = self._encoder.gps_global_origin(self._commander.origin, now_s)
            out += [(link, origin) for link in self._schedulers if link not in unheard]
        return out

    def handle(self, msg: mavlink.MAVLink_message, link: str, now_s: float) -> Outgoing:
        """Process one decoded message received on ``link`` at simulation time ``now_s``
        [s]; returns the replies (COMMAND_ACK to the sender's link, PARAM_VALUE, ...).

        Raises
        ------
        ValueError
            For a link name that is not one of :attr:`links` (a runner bug, not input).
        """
        if link not in self._schedulers:
            raise ValueError(f"unknown link {link!r}; links are {self.links}")
        self._held_until_s = -math.inf
        kind = msg.get_type()
        handler = self._handlers.get(kind)
        if handler is None:
            if kind != "HEARTBEAT":
                self.counters["ignored_message"] += 1
            return []
        return handler(self, msg, link, now_s)

    # ------------------------------------------------------------ handlers

    def _for_us(self, target_system: int, target_component: int, broadcast_ok: bool) -> bool:
        system_ok = target_system == self.system_id or (broadcast_ok and target_system == 0)
        component_ok = target_component in (self.component_id, 0)
        if system_ok and component_ok:
            return True
        self.counters["not_for_us"] += 1
        return False

    def _attitude_target(self, msg, link: str, now_s: float) -> Outgoing:
        if not self._for_us(msg.target_system, msg.target_component, broadcast_ok=True):
            return []
        if msg.type_mask & M.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE:
            self.counters["rate_setpoint_unsupported"] += 1
            return []
        thrust = 0.0
        if not msg.type_mask & M.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE:
            thrust = float(msg.thrust)
        try:
            q_enu = quaternion_enu_flu_from_ned_frd(msg.q)
            setpoint = AttitudeSetpoint(q_enu, thrust)
        except ValueError:
            self.counters["invalid_setpoint"] += 1
            return []
        self._commander.offboard_setpoint(setpoint, now_s)
        return []

    def _position_target(self, msg, link: str, now_s: float) -> Outgoing:
        if not self._for_us(msg.target_system, msg.target_component, broadcast_ok=True):
            return []
        mask = msg.type_mask
        needed = (
            M.POSITION_TARGET_TYPEMASK_X_IGNORE
            | M.POSITION_TARGET_TYPEMASK_Y_IGNORE
            | M.POSITION_TARGET_TYPEMASK_Z_IGNORE
            | M.POSITION_TARGET_TYPEMASK_YAW_IGNORE
            | M.POSITION_TARGET_TYPEMASK_FORCE_SET
        )
        if msg.coordinate_frame != M.MAV_FRAME_LOCAL_NED or mask & needed:
            self.counters["position_setpoint_unsupported"] += 1
            return []

        def field(ignore_bit: int, value: float) -> float:
            return 0.0 if mask & ignore_bit else value  # PX4: NaN, a feed-forward of nothing

        v = (
            field(M.POSITION_TARGET_TYPEMASK_VX_IGNORE, msg.vx),
            field(M.POSITION_TARGET_TYPEMASK_VY_IGNORE, msg.vy),
            field(M.POSITION_TARGET_TYPEMASK_VZ_IGNORE, msg.vz),
        )
        a = (
            field(M.POSITION_TARGET_TYPEMASK_AX_IGNORE, msg.afx),
            field(M.POSITION_TARGET_TYPEMASK_AY_IGNORE, msg.afy),
            field(M.POSITION_TARGET_TYPEMASK_AZ_IGNORE, msg.afz),
        )
        values = (msg.x, msg.y, msg.z, *v, *a, msg.yaw)
        if not all(math.isfinite(x) for x in values):
            self.counters["invalid_setpoint"] += 1
            return []
        _, _, yaw = euler_enu_flu_from_ned_frd(0.0, 0.0, msg.yaw)
        east, north, up = enu_from_ned((msg.x, msg.y, msg.z)).tolist()
        v_e, v_n, v_u = enu_from_ned(v).tolist()
        target = PositionTarget(
            east, north, up, yaw, climb_m_s=v_u, velocity_m_s=(v_e, v_n),
            acceleration_m_s2=tuple(enu_from_ned(a).tolist()),
        )  # fmt: skip
        self._commander.offboard_position(target, now_s)
        return []

    def _command(self, msg, link: str, now_s: float) -> Outgoing:
        command = msg.command
        if not self._for_us(
            msg.target_system, msg.target_component, command in _BROADCAST_TARGET_COMMANDS
        ):
            return []
        p = [msg.param1, msg.param2, msg.param3, msg.param4]
        frame = None
        if msg.get_type() == "COMMAND_INT":
            p += [msg.x / 1e7, msg.y / 1e7, msg.z]
            frame = msg.frame
        else:
            p += [msg.param5, msg.param6, msg.param7]
        extra: Outgoing = []
        if command == M.MAV_CMD_DO_SET_MODE:  # PX4 acknowledges it twice: first ACCEPTED
            extra.append((link, self._ack(msg, command, M.MAV_RESULT_ACCEPTED)))
        result = self._run_command(command, p, frame, link, now_s, extra)
        return [*extra, (link, self._ack(msg, command, result))]

    @staticmethod
    def _ack(msg, command: int, result: int) -> mavlink.MAVLink_command_ack_message:
        return M.MAVLink_command_ack_message(
            command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
        )

    def _run_command(
        self, command: int, p: list[float], frame: int | None, link: str, now_s: float,
        extra: Outgoing,
    ) -> int:  # fmt: skip
        """Execute one command; messages it emits go to ``extra``; returns MAV_RESULT_*."""
        c = self._commander
        if command == M.MAV_CMD_COMPONENT_ARM_DISARM:
            if p[0] == 1.0:
                return c.arm(now_s)
            if p[0] == 0.0:
                return c.disarm(p[1] == FORCE_MAGIC)
            return M.MAV_RESULT_UNSUPPORTED
        if command == M.MAV_CMD_DO_SET_MODE:
            return self._set_mode(p[0], p[1], p[2], now_s)
        if command == M.MAV_CMD_NAV_TAKEOFF:
            return c.takeoff(self._takeoff_height(p[6], frame), now_s)
        if command == M.MAV_CMD_NAV_LAND:
            return c.land(now_s)
        if command == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return c.request_mode(Px4Mode.AUTO_RTL, now_s)
        if command == M.MAV_CMD_SET_MESSAGE_INTERVAL:
            msg_id = _finite_int(p[0])
            if msg_id is None:
                return M.MAV_RESULT_FAILED
            try:
                self._schedulers[link].set_interval(msg_id, p[1], round(now_s * 1e6))
            except (KeyError, ValueError):
                return M.MAV_RESULT_FAILED
            return M.MAV_RESULT_ACCEPTED
        if command == M.MAV_CMD_GET_MESSAGE_INTERVAL:
            msg_id = _finite_int(p[0])
            interval = self._schedulers[link].interval_us(msg_id) if msg_id is not None else None
            reply = M.MAVLink_message_interval_message(
                msg_id or 0, -1 if interval is None else interval
            )
            extra.append((link, reply))
            return M.MAV_RESULT_ACCEPTED
        requested = {
            M.MAV_CMD_REQUEST_MESSAGE: _finite_int(p[0]),
            M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: M.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
            M.MAV_CMD_GET_HOME_POSITION: M.MAVLINK_MSG_ID_HOME_POSITION,
        }
        if command in requested:
            reply = self._requested_message(requested[command], now_s)
            if reply is None:
                return M.MAV_RESULT_DENIED
            extra.append((link, reply))
            return M.MAV_RESULT_ACCEPTED
        self.counters["unsupported_command"] += 1
        return M.MAV_RESULT_UNSUPPORTED

    def _requested_message(
        self, msg_id: int | None, now_s: float
    ) -> mavlink.MAVLink_message | None:
        if msg_id == M.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return self._encoder.autopilot_version(self.system_id)
        if msg_id == M.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN:
            origin = self._commander.origin
            return None if origin is None else self._encoder.gps_global_origin(origin, now_s)
        if msg_id is None or self._last is None or not self._encoder.can_build(msg_id):
            return None
        return self._encoder.build(msg_id, now_s, self._last, self._status())

    def _takeoff_height(self, z: float, frame: int | None) -> float | None:
        """NAV_TAKEOFF altitude as a world height [m]: AMSL (COMMAND_LONG param7, global
        frames) or above home (relative frames); None for NaN (use MIS_TAKEOFF_ALT)."""
        if not math.isfinite(z):
            return None
        if frame in _RELATIVE_FRAMES:
            home = self._commander.home
            return z + (home.up_m if home is not None else 0.0)
        origin = self._commander.origin or self.geo
        return z - origin.altitude_amsl_m

    def _set_mode(self, base_mode: float, main: float, sub: float, now_s: float) -> int:
        base, main_i, sub_i = _finite_int(base_mode), _finite_int(main), _finite_int(sub or 0.0)
        if base is None or not base & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED or main_i is None:
            return M.MAV_RESULT_TEMPORARILY_REJECTED  # PX4 main (measured)
        mode = Px4Mode.from_main_sub(main_i, sub_i or 0)
        if mode is None or mode == Px4Mode.AUTO_READY:
            return M.MAV_RESULT_TEMPORARILY_REJECTED
        if mode == Px4Mode.AUTO_TAKEOFF:
            return self._commander.takeoff(None, now_s)
        return self._commander.request_mode(mode, now_s)

    def _set_mode_message(self, msg, link: str, now_s: float) -> Outgoing:
        if msg.target_system != self.system_id:
            self.counters["not_for_us"] += 1
            return []
        result = self._set_mode(
            float(msg.base_mode),
            float((msg.custom_mode >> 16) & 0xFF),
            float((msg.custom_mode >> 24) & 0xFF),
            now_s,
        )
        return [(link, self._ack(msg, M.MAV_CMD_DO_SET_MODE, result))]

    def _set_gps_global_origin(self, msg, link: str, now_s: float) -> Outgoing:
        if msg.target_system != self.system_id:
            self.counters["not_for_us"] += 1
            return []
        if self.aiding == "gps":
            self.counters["origin_ignored"] += 1
            return []
        try:
            origin = GeoReference(msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3)
        except ValueError:
            self.counters["invalid_origin"] += 1
            return []
        if self._commander.set_global_origin(origin, now_s):
            self._origin_pending = True
        return []

    def _param_value(self, name: str) -> mavlink.MAVLink_param_value_message:
        p = self.params
        return M.MAVLink_param_value_message(
            name.encode(),
            p.wire_value(name),
            PARAMETERS[name].mav_type,
            len(p.names),
            p.index(name),
        )

    def _param_request_list(self, msg, link: str, now_s: float) -> Outgoing:
        if not self._for_us(msg.target_system, msg.target_component, broadcast_ok=False):
            return []
        return [(link, self._param_value(name)) for name in self.params.names]

    def _param_request_read(self, msg, link: str, now_s: float) -> Outgoing:
        if not self._for_us(msg.target_system, msg.target_component, broadcast_ok=False):
            return []
        names = self.params.names
        if msg.param_index >= 0:
            if msg.param_index < len(names):
                return [(link, self._param_value(names[msg.param_index]))]
        elif msg.param_id in PARAMETERS:
            return [(link, self._param_value(msg.param_id))]
        self.counters["unknown_param"] += 1
        return []

    def _param_set(self, msg, link: str, now_s: float) -> Outgoing:
        if not self._for_us(msg.target_system, msg.target_component, broadcast_ok=False):
            return []
        name = msg.param_id
        spec = PARAMETERS.get(name)
        if spec is None:
            self.counters["unknown_param"] += 1
            return []
        if msg.param_type != spec.mav_type:
            self.counters["param_type_mismatch"] += 1
            return []
        try:
            self.params.set(name, Px4Params.decode_wire(name, msg.param_value))
        except (UnknownParamError, ParamError):
            self.counters["refused_param"] += 1
            return [(link, self._param_value(name))]
        return [(each, self._param_value(name)) for each in self.links]

    def _ping(self, msg, link: str, now_s: float) -> Outgoing:
        if msg.target_system != 0 or msg.target_component != 0:
            return []  # an answer to a ping of ours (PX4 takes the latency), or not for us
        reply = M.MAVLink_ping_message(
            msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()
        )
        return [(link, reply)]

    def _timesync(self, msg, link: str, now_s: float) -> Outgoing:
        if msg.tc1 != 0:
            return []
        return [(link, M.MAVLink_timesync_message(round(now_s * 1e9), msg.ts1))]

    _handlers: ClassVar[dict] = {
        "SET_ATTITUDE_TARGET": _attitude_target,
        "SET_POSITION_TARGET_LOCAL_NED": _position_target,
        "COMMAND_LONG": _command,
        "COMMAND_INT": _command,
        "SET_MODE": _set_mode_message,
        "SET_GPS_GLOBAL_ORIGIN": _set_gps_global_origin,
        "PARAM_REQUEST_LIST": _param_request_list,
        "PARAM_REQUEST_READ": _param_request_read,
        "PARAM_SET": _param_set,
        "TIMESYNC": _timesync,
        "PING": _ping,
    }

    # ------------------------------------------------------------ helpers

    def _status(self) -> VehicleStatus:
        c = self._commander
        return VehicleStatus(
            mode=c.mode,
            intended_mode=c.user_mode,
            armed=c.armed,
            landed_state=c.landed_state,
            failsafe=c.failsafe,
            prearm_ok=c.prearm_ok,
            home=c.home,
            origin=c.origin,
            mav_type=int(self.params["MAV_TYPE"]),
            setpoint=c.setpoint_flown,
            estimator_resets=c.estimator_resets,
        )

"""The onboard link's streams: only what the companion reads, at the rates it needs.

PX4 streams about 30 message types on its onboard link by default, some 406 messages/s
(measured on the PX4 SITL build: ATTITUDE at 100 Hz, HIGHRES_IMU, ATTITUDE_QUATERNION and
GLOBAL_POSITION_INT at 50 Hz, ...), and pymavlink parses each in Python (about 10 us a
message). The companion reads four of them (:func:`read_streams`): the pose (ODOMETRY, or
LOCAL_POSITION_NED and ATTITUDE_QUATERNION with ``pose_from = "local_position"``), the
battery (SYS_STATUS), the landed state (EXTENDED_SYS_STATE) and HEARTBEAT; the rest of
what it reads are answers to its own requests (COMMAND_ACK, PARAM_VALUE,
MESSAGE_INTERVAL, GPS_GLOBAL_ORIGIN).

:class:`OnboardStreams` asks those streams at their rates, turns every other stream off
(MAV_CMD_SET_MESSAGE_INTERVAL with -1) and, at the end of the mission, gives each stream
it changed back PX4's default for the link (interval 0). Which streams are on comes from
PX4 itself: GET_MESSAGE_INTERVAL of each of PX4's onboard-mode defaults
(:data:`PX4_ONBOARD_STREAMS`) and of each message the vehicle sent so far, a stream being
on when PX4 reports an interval, or reports -1 (sent on every update, as GPS_RAW_INT) for
one of its defaults that arrives. Never touched (:data:`UNTOUCHED`): HEARTBEAT (PX4
refuses its interval), MISSION_CURRENT (not a stream: PX4's mission manager sends it,
refused), GPS_GLOBAL_ORIGIN (PX4 sends it only when the origin changes, which is the echo
the preflight waits for) and the answers. A refusal or a silence is noted, never fatal:
what PX4 keeps sending costs CPU, not safety.

With ODOMETRY at 125 Hz the link then carries about 149 messages/s (ODOMETRY 125,
SYS_STATUS 20, EXTENDED_SYS_STATE 1, HEARTBEAT 1, MISSION_CURRENT 1 and PX4's events,
measured on the PX4 SITL build), about 13 kB/s.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping

from pymavlink.dialects.v20 import common as mavlink2
from pymavlink.dialects.v20 import development

from companion.link import MavlinkLink
from companion.link.errors import CommandDenied, LinkError
from companion.link.telemetry import PoseSource

__all__ = [
    "BATTERY_RATE_HZ",
    "LANDED_RATE_HZ",
    "PX4_ONBOARD_STREAMS",
    "UNTOUCHED",
    "OnboardStreams",
    "read_streams",
    "stream_name",
    "streams_to_stop",
]

Note = Callable[[str, str], None]

BATTERY_RATE_HZ = 20.0
"""Rate asked of SYS_STATUS, the battery's voltage and current [Hz]: the thrust scale
follows the voltage, which a grasp's load step drops at once (PX4's onboard link sends it
at 5 Hz by default)."""

LANDED_RATE_HZ = 1.0
"""Rate asked of EXTENDED_SYS_STATE, PX4's landed state [Hz] (5 Hz by default): read
before arming (on the ground) and in flight as a ground contact, where the height checked
every cycle is the fast detection; PX4's land detector itself decides after its trigger
time (LNDMC_TRIG_TIME, 1 s)."""

_COMMAND_TIMEOUT_S = 0.3
"""Wait for each answer [s] (PX4 answers a stream command in about 10 ms)."""
_COMMAND_ATTEMPTS = 2

_PX4_ONBOARD_NAMES = (
    "TIMESYNC CAMERA_TRIGGER HIGHRES_IMU LOCAL_POSITION_NED ATTITUDE ALTITUDE DISTANCE_SENSOR "
    "MOUNT_ORIENTATION OBSTACLE_DISTANCE ODOMETRY ADSB_VEHICLE ATTITUDE_QUATERNION "
    "ATTITUDE_TARGET AVAILABLE_MODES BATTERY_STATUS CAMERA_IMAGE_CAPTURED CURRENT_MODE "
    "EFI_STATUS ESTIMATOR_STATUS EXTENDED_SYS_STATE GIMBAL_DEVICE_ATTITUDE_STATUS "
    "GIMBAL_DEVICE_SET_ATTITUDE GIMBAL_MANAGER_STATUS GLOBAL_POSITION_INT GNSS_INTEGRITY "
    "GPS2_RAW GPS_GLOBAL_ORIGIN GPS_RAW_INT GPS_STATUS HOME_POSITION HYGROMETER_SENSOR "
    "NAV_CONTROLLER_OUTPUT OPEN_DRONE_ID_LOCATION OPEN_DRONE_ID_SYSTEM "
    "OPEN_DRONE_ID_ARM_STATUS OPTICAL_FLOW_RAD ORBIT_EXECUTION_STATUS PING "
    "POSITION_TARGET_GLOBAL_INT POSITION_TARGET_LOCAL_NED RAW_RPM RC_CHANNELS SCALED_PRESSURE "
    "SERVO_OUTPUT_RAW SYS_STATUS SYSTEM_TIME VFR_HUD VIBRATION WIND_COV DEBUG "
    "DEBUG_FLOAT_ARRAY DEBUG_VECT NAMED_VALUE_FLOAT"
).split()
"""PX4's onboard-mode streams (``Mavlink::configure_streams_to_default``,
``MAVLINK_MODE_ONBOARD``) that pymavlink's common or development dialect names."""

_LINK_NODE_STATUS = 8
_TIME_ESTIMATE_TO_TARGET = 380
"""Two onboard streams of PX4 outside pymavlink's dialects, by id (measured: PX4 SITL
sends both, at 1 and 0.3 messages/s, and accepts their interval)."""


def _message_id(name: str) -> int:
    key = f"MAVLINK_MSG_ID_{name}"
    return int(getattr(mavlink2, key, None) or getattr(development, key))


PX4_ONBOARD_STREAMS: frozenset[int] = frozenset(
    {_message_id(n) for n in _PX4_ONBOARD_NAMES} | {_LINK_NODE_STATUS, _TIME_ESTIMATE_TO_TARGET}
)
"""Message ids of PX4's default streams on an onboard link."""

UNTOUCHED: frozenset[int] = frozenset(
    {
        mavlink2.MAVLINK_MSG_ID_HEARTBEAT,
        mavlink2.MAVLINK_MSG_ID_MISSION_CURRENT,
        mavlink2.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN,
        mavlink2.MAVLINK_MSG_ID_COMMAND_ACK,
        mavlink2.MAVLINK_MSG_ID_PARAM_VALUE,
        mavlink2.MAVLINK_MSG_ID_MESSAGE_INTERVAL,
    }
)
"""Messages whose interval the companion never changes (see the module docstring)."""


def stream_name(msg_id: int) -> str:
    """The message's name, or ``#id`` for one outside pymavlink's dialects."""
    for dialect in (mavlink2, development):
        entry = dialect.mavlink_map.get(msg_id)
        if entry is not None:
            return str(entry.msgname)
    return f"#{msg_id}"


def read_streams(pose_from: PoseSource, pose_rate_hz: float) -> dict[int, float]:
    """The streams the companion reads and their rates [Hz], by message id: the pose at
    ``pose_rate_hz`` (ODOMETRY, or LOCAL_POSITION_NED and ATTITUDE_QUATERNION),
    EXTENDED_SYS_STATE at :data:`LANDED_RATE_HZ`, SYS_STATUS at :data:`BATTERY_RATE_HZ`. HEARTBEAT,
    at PX4's fixed 1 Hz, is not asked."""
    if not pose_rate_hz > 0.0:
        raise ValueError(f"pose_rate_hz must be positive, got {pose_rate_hz}")
    if pose_from == "odometry":
        pose = {mavlink2.MAVLINK_MSG_ID_ODOMETRY: pose_rate_hz}
    else:
        pose = {
            mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED: pose_rate_hz,
            mavlink2.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: pose_rate_hz,
        }
    return {
        **pose,
        mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: LANDED_RATE_HZ,
        mavlink2.MAVLINK_MSG_ID_SYS_STATUS: BATTERY_RATE_HZ,
    }


def streams_to_stop(
    intervals_us: Mapping[int, int | None], seen: Collection[int], read: Collection[int]
) -> list[int]:
    """The streams to turn off, in id order: of ``intervals_us`` (message id -> the
    interval PX4 reported [us], None when it did not answer), those on and not ``read``
    nor :data:`UNTOUCHED`. On: a positive interval, or -1 (PX4: not streamed, or sent on
    every update) for one of :data:`PX4_ONBOARD_STREAMS` that was ``seen`` arriving."""
    out = []
    for msg_id, interval in sorted(intervals_us.items()):
        if msg_id in read or msg_id in UNTOUCHED or interval is None:
            continue
        if interval > 0 or (interval == -1 and msg_id in PX4_ONBOARD_STREAMS and msg_id in seen):
            out.append(msg_id)
    return out


class OnboardStreams:
    """The streams of one link, set for the mission and given back afterwards.

    :meth:`ask` sets the streams read (before the pose rate is measured), :meth:`stop_unread`
    turns the others off (meanwhile: it waits for answers only), :meth:`restore` gives
    every stream changed PX4's default back; each notes refusals through ``note`` and
    raises nothing but cancellation.
    """

    def __init__(self, link: MavlinkLink, note: Note) -> None:
        self.link = link
        self.note = note
        self.asked: dict[int, float] = {}
        """Streams read, asked at these rates [Hz] (accepted or not)."""
        self.stopped: list[int] = []
        """Streams turned off (accepted)."""
        self.changed: list[int] = []
        """Every stream sent a new interval, in order (restored at the end, also when
        the answer did not come: the change may have been made)."""
        self.before_us: dict[int, int | None] = {}
        """The intervals PX4 reported before the change [us] (streams stopped)."""

    async def ask(self, rates_hz: Mapping[int, float]) -> None:
        """Ask each stream of ``rates_hz`` (message id -> rate [Hz])."""
        for msg_id, rate in rates_hz.items():
            self.asked[msg_id] = rate
            self.changed.append(msg_id)
            try:
                await self.link.set_message_interval(
                    msg_id, rate, timeout_s=_COMMAND_TIMEOUT_S, attempts=_COMMAND_ATTEMPTS
                )
            except LinkError as exc:
                self.note("streams", f"{stream_name(msg_id)} at {rate:g} Hz not set: {exc}")

    async def stop_unread(self) -> None:
        """Turn off every stream PX4 sends that is not asked (:func:`streams_to_stop`).
        Ends with a note at the first question not answered (the link is gone)."""
        seen = set(self.link.messages_from_vehicle())
        candidates = sorted((PX4_ONBOARD_STREAMS | seen) - UNTOUCHED - set(self.asked))
        for msg_id in candidates:
            try:
                self.before_us[msg_id] = await self.link.get_message_interval(
                    msg_id, timeout_s=_COMMAND_TIMEOUT_S, attempts=_COMMAND_ATTEMPTS
                )
            except CommandDenied:
                self.before_us[msg_id] = None
            except LinkError as exc:
                self.note("streams", f"streams left as the vehicle sends them: {exc}")
                return
        for msg_id in streams_to_stop(self.before_us, seen, self.asked):
            self.changed.append(msg_id)
            try:
                await self.link.set_message_interval(
                    msg_id, 0.0, timeout_s=_COMMAND_TIMEOUT_S, attempts=_COMMAND_ATTEMPTS
                )
            except CommandDenied as exc:
                self.note("streams", f"{stream_name(msg_id)} not stopped: {exc}")
                continue
            except LinkError as exc:
                self.note("streams", f"{stream_name(msg_id)} not stopped: {exc}")
                return
            self.stopped.append(msg_id)

    async def restore(self) -> None:
        """Give each changed stream PX4's default for the link back (interval 0). The
        first stream whose answer does not come ends it (the link is gone), with a note
        naming what was not restored."""
        changed, self.changed = self.changed, []
        for i, msg_id in enumerate(changed):
            try:
                await self.link.default_message_interval(
                    msg_id, timeout_s=_COMMAND_TIMEOUT_S, attempts=_COMMAND_ATTEMPTS
                )
            except CommandDenied as exc:
                self.note("streams", f"{stream_name(msg_id)} not restored: {exc}")
            except LinkError as exc:
                left = ", ".join(stream_name(m) for m in changed[i:])
                self.note("streams", f"not restored to PX4's defaults: {left} ({exc})")
                return

    def describe(self) -> dict[str, object]:
        """What was asked and stopped, for the report."""
        return {
            "asked_hz": {stream_name(m): r for m, r in self.asked.items()},
            "stopped": [stream_name(m) for m in self.stopped],
        }

"""The simulated PX4's streams: default rates per link and when each message is due.

Default rates are those PX4 main reports (GET_MESSAGE_INTERVAL) on its SITL links: the
onboard link (``mavlink ... -m onboard``) and the GCS link ("normal" mode with the SITL
start-up script's 50 Hz overrides). Every stream is changeable per link with
MAV_CMD_SET_MESSAGE_INTERVAL (-1 disables, 0 restores the default) except HEARTBEAT,
which PX4 refuses (FAILED); a message this vehicle builds but does not stream by default
can be switched on. Scheduling is in simulation time with integer microseconds: a stream
with interval T is due at k T; a stream that fell behind (a coarse caller) is sent once and
rescheduled from now, never in a burst. HEARTBEAT is a strict 1 Hz stream: a mode change
shows in the next one, as on PX4.

Streams of the estimate (:data:`ESTIMATOR_STREAMS`: ODOMETRY, LOCAL_POSITION_NED,
GLOBAL_POSITION_INT, ATTITUDE, ATTITUDE_QUATERNION) go out only at an estimator output
(every 8 ms): asked faster they arrive at the estimator's 125 Hz, asked slower they keep
their average rate on the 8 ms grid (30 Hz: 32 and 40 ms apart), as measured on PX4.

What each message holds is :mod:`sitl.px4.telemetry`'s.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from pymavlink.dialects.v20 import common as mavlink
from pymavlink.dialects.v20 import development

__all__ = ["ESTIMATOR_STREAMS", "GCS_RATES_HZ", "ONBOARD_RATES_HZ", "StreamScheduler"]

M = mavlink
CURRENT_MODE = development.MAVLINK_MSG_ID_CURRENT_MODE
"""CURRENT_MODE (436), in MAVLink's development dialect; PX4 streams it."""
ONBOARD_RATES_HZ: dict[int, float] = {
    M.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    M.MAVLINK_MSG_ID_SYS_STATUS: 5.0,
    M.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    M.MAVLINK_MSG_ID_PING: 1.0,
    M.MAVLINK_MSG_ID_ATTITUDE: 100.0,
    M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 50.0,
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 30.0,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 50.0,
    M.MAVLINK_MSG_ID_VFR_HUD: 10.0,
    M.MAVLINK_MSG_ID_ATTITUDE_TARGET: 10.0,
    M.MAVLINK_MSG_ID_HIGHRES_IMU: 50.0,
    M.MAVLINK_MSG_ID_TIMESYNC: 10.0,
    M.MAVLINK_MSG_ID_ALTITUDE: 10.0,
    M.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,
    M.MAVLINK_MSG_ID_ESTIMATOR_STATUS: 1.0,
    M.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 5.0,
    M.MAVLINK_MSG_ID_ODOMETRY: 30.0,
    CURRENT_MODE: 0.5,
}
"""Default rates [Hz] of the onboard (API) link, as PX4 main reports them."""

GCS_RATES_HZ: dict[int, float] = {
    M.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    M.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    M.MAVLINK_MSG_ID_PING: 0.1,
    M.MAVLINK_MSG_ID_ATTITUDE: 50.0,
    M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 50.0,
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 50.0,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 50.0,
    M.MAVLINK_MSG_ID_VFR_HUD: 4.0,
    M.MAVLINK_MSG_ID_ATTITUDE_TARGET: 50.0,
    M.MAVLINK_MSG_ID_ALTITUDE: 1.0,
    M.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,
    M.MAVLINK_MSG_ID_ESTIMATOR_STATUS: 0.5,
    M.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    CURRENT_MODE: 0.5,
}
"""Default rates [Hz] of the GCS link, as PX4 main's SITL reports them."""

ESTIMATOR_STREAMS = frozenset(
    {
        M.MAVLINK_MSG_ID_ODOMETRY,
        M.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
        M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
        M.MAVLINK_MSG_ID_ATTITUDE,
        M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
    }
)
"""Streams sent only at an estimator output (their data is the estimate)."""

_FIXED_INTERVAL = frozenset({M.MAVLINK_MSG_ID_HEARTBEAT})
"""Streams whose interval PX4 refuses to change (SET_MESSAGE_INTERVAL: FAILED)."""


class StreamScheduler:
    """When each message of one link is due, in simulation time.

    Parameters
    ----------
    default_rates_hz : mapping of message id to rate [Hz]
        The link's default streams and rates.
    streamable : iterable of message ids
        Every message this link can stream (the defaults and those switched on by
        SET_MESSAGE_INTERVAL).
    """

    def __init__(self, default_rates_hz: Mapping[int, float], streamable) -> None:
        self._known = frozenset(streamable) | frozenset(default_rates_hz)
        self._default_us: dict[int, int | None] = dict.fromkeys(self._known)
        for msg_id, rate in default_rates_hz.items():
            self._default_us[msg_id] = round(1e6 / rate) if rate > 0 else None
        self._interval_us: dict[int, int] = {
            m: i for m, i in self._default_us.items() if i is not None
        }
        self._next_us: dict[int, int] = dict.fromkeys(self._interval_us, 0)
        self._earliest_us = 0
        """No stream is due before this time [us] (``due`` returns at once before it),
        except estimator streams waiting for an estimate (:attr:`_waiting`)."""
        self._waiting = False
        """An estimator stream is due and waits for the next fresh estimate."""

    @property
    def streams(self) -> list[int]:
        """Message ids this link can stream."""
        return sorted(self._known)

    @property
    def next_due_us(self) -> int:
        """Simulation time [us] before which :meth:`due` without a fresh estimate returns
        nothing and changes nothing (estimator streams come with the next estimate)."""
        return self._earliest_us

    def interval_us(self, msg_id: int) -> int | None:
        """Current interval [us] of a stream, None when disabled or not a stream."""
        return self._interval_us.get(msg_id)

    def set_interval(self, msg_id: int, interval_us: float, now_us: int) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL: -1 disables, 0 restores the default, > 0 sets [us].

        Raises
        ------
        KeyError
            The message is not a stream of this vehicle, or its interval is fixed
            (HEARTBEAT).
        ValueError
            A non-finite interval or one below -1.
        """
        if msg_id not in self._known or msg_id in _FIXED_INTERVAL:
            raise KeyError(msg_id)
        if not math.isfinite(interval_us) or interval_us < -1.0:
            raise ValueError(f"interval {interval_us!r} us")
        if interval_us == 0.0:
            interval = self._default_us[msg_id]
        else:
            interval = None if interval_us < 0.0 else max(round(interval_us), 1)
        if interval is None:
            self._interval_us.pop(msg_id, None)
            self._next_us.pop(msg_id, None)
            return
        self._interval_us[msg_id] = interval
        self._next_us[msg_id] = now_us
        self._earliest_us = min(self._earliest_us, now_us)

    def due(self, now_us: int, estimate_fresh: bool) -> list[int]:
        """Message ids due at ``now_us``; each is rescheduled one interval later. Streams
        of :data:`ESTIMATOR_STREAMS` wait for a step with ``estimate_fresh``."""
        if now_us < self._earliest_us and not (estimate_fresh and self._waiting):
            return []
        out = []
        next_us = self._next_us
        earliest = None
        waiting = False
        for msg_id, interval in self._interval_us.items():
            nxt = next_us[msg_id]
            if now_us >= nxt:
                if estimate_fresh or msg_id not in ESTIMATOR_STREAMS:
                    out.append(msg_id)
                    nxt += interval
                    if nxt <= now_us:
                        nxt = now_us + interval
                    next_us[msg_id] = nxt
                else:
                    waiting = True
                    continue  # due, waits for an estimate: not a reason to look sooner
            if earliest is None or nxt < earliest:
                earliest = nxt
        self._waiting = waiting
        # With none enabled (or all waiting), check again every time.
        self._earliest_us = now_us if earliest is None else earliest
        return out

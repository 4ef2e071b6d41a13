"""What each request of the flight sequence (:class:`~companion.mission.sequence.Request`)
asks PX4 over the MAVLink link: one awaitable per request, which returns once PX4 has
acknowledged it and raises :class:`~companion.link.errors.CommandError` or
:class:`~companion.link.errors.ParamError` when PX4 refuses or does not answer."""

from __future__ import annotations

import math
from collections.abc import Awaitable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from companion.link import MavlinkLink
from companion.link.px4_modes import px4_mode
from companion.mission.sequence import Px4Request, Request

__all__ = ["ask_px4"]

_PX4_DEFAULTS = [0, 0, 0] + [math.nan] * 4
"""Parameters of NAV_TAKEOFF and NAV_LAND that leave PX4 its own values (its take-off
altitude parameter, the current position)."""


def ask_px4(link: MavlinkLink, command: Px4Request) -> Awaitable[Any]:
    """The link's call for ``command``: arm, the take-off altitude (``MIS_TAKEOFF_ALT``,
    ``command.value`` [m]), take-off, OFFBOARD, hold (PX4's LOITER) or land."""
    request = command.request
    if request == Request.ARM:
        return link.arm()
    if request == Request.TAKEOFF_ALTITUDE:
        return link.param_set("MIS_TAKEOFF_ALT", command.value)
    if request == Request.TAKEOFF:
        return link.command_long(mavlink2.MAV_CMD_NAV_TAKEOFF, _PX4_DEFAULTS)
    if request == Request.OFFBOARD:
        return link.set_mode_px4(*px4_mode("OFFBOARD"))
    if request == Request.HOLD:
        return link.set_mode_px4(*px4_mode("LOITER"))
    if request == Request.LAND:
        return link.command_long(mavlink2.MAV_CMD_NAV_LAND, _PX4_DEFAULTS)
    raise ValueError(f"no PX4 request {request!r}")

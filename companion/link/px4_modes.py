"""PX4 flight modes as MAVLink carries them (PX4 ``src/modules/commander/px4_custom_mode.h``).

HEARTBEAT.custom_mode and the DO_SET_MODE command carry a PX4 mode as a main mode and a
sub mode: ``custom_mode = main << 16 | sub << 24`` (the low 16 bits are reserved), and
DO_SET_MODE sends ``param1 = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, param2 = main,
param3 = sub``. Sub modes are used by AUTO (takeoff, land, ...) and POSCTL (orbit, slow).
The names below follow pymavlink's ``mavutil.px4_map`` where it has the mode.
"""

from __future__ import annotations

from enum import IntEnum
from typing import NamedTuple

from companion.link.errors import UnknownModeError

__all__ = [
    "PX4_MODES",
    "Px4AutoSubMode",
    "Px4MainMode",
    "Px4Mode",
    "Px4PosctlSubMode",
    "decode_custom_mode",
    "px4_mode",
]


class Px4MainMode(IntEnum):
    """``PX4_CUSTOM_MAIN_MODE``."""

    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7
    RATTITUDE_LEGACY = 8
    SIMPLE = 9
    TERMINATION = 10
    ALTITUDE_CRUISE = 11


class Px4AutoSubMode(IntEnum):
    """``PX4_CUSTOM_SUB_MODE_AUTO`` (7 was RTGS, removed from PX4 in 2020)."""

    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6
    RESERVED_DO_NOT_USE = 7
    FOLLOW_TARGET = 8
    PRECLAND = 9
    VTOL_TAKEOFF = 10
    EXTERNAL1 = 11
    EXTERNAL2 = 12
    EXTERNAL3 = 13
    EXTERNAL4 = 14
    EXTERNAL5 = 15
    EXTERNAL6 = 16
    EXTERNAL7 = 17
    EXTERNAL8 = 18


class Px4PosctlSubMode(IntEnum):
    """``PX4_CUSTOM_SUB_MODE_POSCTL``."""

    POSCTL = 0
    ORBIT = 1
    SLOW = 2


class Px4Mode(NamedTuple):
    """A PX4 mode: main mode and sub mode (0 where the main mode has none)."""

    main: int
    sub: int = 0

    @property
    def custom_mode(self) -> int:
        """The HEARTBEAT / SET_MODE ``custom_mode`` word: ``main << 16 | sub << 24``."""
        return (self.main & 0xFF) << 16 | (self.sub & 0xFF) << 24

    @property
    def name(self) -> str:
        """The name in :data:`PX4_MODES`, or ``UNKNOWN(main.sub)``."""
        return _NAMES.get(self, f"UNKNOWN({self.main}.{self.sub})")


_M, _A, _P = Px4MainMode, Px4AutoSubMode, Px4PosctlSubMode
PX4_MODES: dict[str, Px4Mode] = {
    "MANUAL": Px4Mode(_M.MANUAL),
    "ALTCTL": Px4Mode(_M.ALTCTL),
    "POSCTL": Px4Mode(_M.POSCTL, _P.POSCTL),
    "ORBIT": Px4Mode(_M.POSCTL, _P.ORBIT),
    "POSCTL_SLOW": Px4Mode(_M.POSCTL, _P.SLOW),
    "READY": Px4Mode(_M.AUTO, _A.READY),
    "TAKEOFF": Px4Mode(_M.AUTO, _A.TAKEOFF),
    "LOITER": Px4Mode(_M.AUTO, _A.LOITER),
    "MISSION": Px4Mode(_M.AUTO, _A.MISSION),
    "RTL": Px4Mode(_M.AUTO, _A.RTL),
    "LAND": Px4Mode(_M.AUTO, _A.LAND),
    "FOLLOWME": Px4Mode(_M.AUTO, _A.FOLLOW_TARGET),
    "PRECLAND": Px4Mode(_M.AUTO, _A.PRECLAND),
    "VTOL_TAKEOFF": Px4Mode(_M.AUTO, _A.VTOL_TAKEOFF),
    **{f"EXTERNAL{i}": Px4Mode(_M.AUTO, _A.EXTERNAL1 + i - 1) for i in range(1, 9)},
    "ACRO": Px4Mode(_M.ACRO),
    "OFFBOARD": Px4Mode(_M.OFFBOARD),
    "STABILIZED": Px4Mode(_M.STABILIZED),
    "RATTITUDE": Px4Mode(_M.RATTITUDE_LEGACY),
    "TERMINATION": Px4Mode(_M.TERMINATION),
    "ALTITUDE_CRUISE": Px4Mode(_M.ALTITUDE_CRUISE),
}
"""Every PX4 mode by name (the tuples compare equal to plain ``(main, sub)``)."""
_NAMES = {mode: name for name, mode in PX4_MODES.items()}


def px4_mode(name: str) -> Px4Mode:
    """The mode of a name in :data:`PX4_MODES` (case-insensitive); ``UnknownModeError``."""
    try:
        return PX4_MODES[name.upper()]
    except KeyError:
        raise UnknownModeError(
            f"unknown PX4 mode {name!r}; known: {', '.join(PX4_MODES)}"
        ) from None


def decode_custom_mode(custom_mode: int) -> Px4Mode:
    """Main and sub mode of a HEARTBEAT ``custom_mode`` word (PX4 autopilots only)."""
    return Px4Mode((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)

"""PX4 flight modes and how PX4 encodes them in HEARTBEAT / SET_MODE / DO_SET_MODE.

PX4 (``src/modules/commander/px4_custom_mode.h``) packs its mode into the 32-bit
``custom_mode`` as a union ``{uint16 reserved; uint8 main_mode; uint8 sub_mode}``, i.e.
``custom_mode = main_mode << 16 | sub_mode << 24``. Main modes: MANUAL 1, ALTCTL 2,
POSCTL 3, AUTO 4, ACRO 5, OFFBOARD 6, STABILIZED 7; AUTO sub modes: READY 1, TAKEOFF 2,
LOITER 3 (shown as "Hold"), MISSION 4, RTL 5, LAND 6. DO_SET_MODE carries the same numbers
as floats: param1 = base mode (must have MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), param2 = main
mode, param3 = sub mode.

The HEARTBEAT ``base_mode`` follows PX4's ``get_mav_mode_state``: CUSTOM_MODE_ENABLED
always, SAFETY_ARMED while armed, plus MANUAL_INPUT / STABILIZE / GUIDED / AUTO flags per
mode. pymavlink's ``mavutil.interpret_px4_mode`` decodes only ``custom_mode``.
"""

from __future__ import annotations

import enum

from pymavlink.dialects.v20 import common as mavlink

__all__ = ["Px4Mode", "base_mode_flags"]

_MANUAL = mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
_STAB = mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
_GUIDED = mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
_AUTO = mavlink.MAV_MODE_FLAG_AUTO_ENABLED


class Px4Mode(enum.Enum):
    """A PX4 navigation mode as (main mode, sub mode); its name is PX4's display name."""

    MANUAL = (1, 0)
    ALTCTL = (2, 0)
    POSCTL = (3, 0)
    AUTO_READY = (4, 1)
    AUTO_TAKEOFF = (4, 2)
    AUTO_LOITER = (4, 3)
    AUTO_MISSION = (4, 4)
    AUTO_RTL = (4, 5)
    AUTO_LAND = (4, 6)
    ACRO = (5, 0)
    OFFBOARD = (6, 0)
    STABILIZED = (7, 0)

    @property
    def main_mode(self) -> int:
        """PX4_CUSTOM_MAIN_MODE_* number."""
        return self.value[0]

    @property
    def sub_mode(self) -> int:
        """PX4_CUSTOM_SUB_MODE_AUTO_* number (0 outside AUTO)."""
        return self.value[1]

    @property
    def custom_mode(self) -> int:
        """HEARTBEAT.custom_mode: ``main << 16 | sub << 24``."""
        return (self.main_mode << 16) | (self.sub_mode << 24)

    @property
    def display_name(self) -> str:
        """PX4's name, e.g. ``AUTO.LOITER`` or ``OFFBOARD``."""
        return self.name.replace("_", ".", 1)

    @classmethod
    def from_main_sub(cls, main_mode: int, sub_mode: int) -> Px4Mode | None:
        """The mode with these numbers, or None if PX4 has no such mode.

        Outside AUTO the sub mode is ignored, as PX4's commander does; AUTO with sub mode
        0 is not a mode.
        """
        if main_mode != 4:
            sub_mode = 0
        try:
            return cls((main_mode, sub_mode))
        except ValueError:
            return None

    @classmethod
    def from_custom_mode(cls, custom_mode: int) -> Px4Mode | None:
        """Decode HEARTBEAT / SET_MODE ``custom_mode`` (None if unknown)."""
        return cls.from_main_sub((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)


_MODE_FLAGS: dict[Px4Mode, int] = {
    Px4Mode.MANUAL: _MANUAL | _STAB,  # multicopter MANUAL is stabilized in PX4
    Px4Mode.STABILIZED: _MANUAL | _STAB,
    Px4Mode.ACRO: _MANUAL,
    Px4Mode.ALTCTL: _MANUAL | _STAB,
    Px4Mode.POSCTL: _MANUAL | _STAB | _GUIDED,
    Px4Mode.OFFBOARD: _AUTO | _STAB | _GUIDED,
}


def base_mode_flags(mode: Px4Mode, armed: bool) -> int:
    """HEARTBEAT.base_mode as PX4 fills it for ``mode`` and the arming state."""
    flags = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    flags |= _MODE_FLAGS.get(mode, _AUTO | _STAB | _GUIDED)
    if armed:
        flags |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    return flags

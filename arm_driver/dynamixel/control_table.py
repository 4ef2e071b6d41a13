"""XM430-W350 control table: the entries the driver uses, with address, size and unit.

Source: ROBOTIS e-Manual, XM430-W350 page (``/docs/en/dxl/x/xm430-w350/``), tables
"Control Table of EEPROM Area" and "Control Table of RAM Area" (address, size, name,
access, default, range, unit), and the included descriptions: Operating Mode(11)
values, Baud Rate(8) values, Drive Mode(10) bits, Status Return Level(68) values,
Goal Position(116) ("4,096 resolution", 0.088 deg per value, CCW increasing seen from
the front), Goal Velocity(104) 0.229 rev/min, Goal Current(102) "about 2.69 mA", Present
Input Voltage(144) 0.1 V, Present Temperature(146) 1 degC, Hardware Error Status(70)
bits (:class:`~arm_driver.errors.HardwareErrorStatus`). Cross-checked against the older
page revision (same addresses and sizes; it also lists Acceleration Limit(40), dropped
by later firmware, so not used here) and the Protocol 2.0 page's examples (Present
Position 132, 4 bytes; Goal Position 116, 4 bytes; Goal Velocity 104, 4 bytes; Present
Input Voltage 144, 2 bytes; Present Temperature 146, 1 byte).

Signedness: the e-Manual gives negative ranges for Homing Offset (-1,044,479 ~
1,044,479), Goal Current (-Current Limit ~ Current Limit), Goal Velocity (-Velocity
Limit ~ Velocity Limit) and Goal Position in extended modes (-1,048,575 ~ 1,048,575);
the Present values mirror them (Present Position is a 4-byte signed count). These are
two's complement; everything else here is unsigned.

Bus Watchdog(98) (RAM, 1 byte, initial 0, firmware v38 and later; e-Manual section
"Bus Watchdog(98)"): 0 turns the watchdog off and clears its error, 1-127 turn it on
with a timeout of value x 20 ms. While Torque Enable(64) is 1 the servo measures the
interval between instruction packets ("all the Instruction Packet in the DYNAMIXEL
Protocol"); when it is longer than the timeout the servo stops and the entry reads -1
(Bus Watchdog Error): Goal PWM(100), Goal Current(102), Goal Velocity(104) and Goal
Position(116) become read-only, a write to them is answered with a Data Range Error,
until the host writes 0. The e-Manual does not say that Torque Enable changes.

Writes to the EEPROM area (addresses 0-63) are refused (Access Error) while Torque
Enable(64) is 1. Unit conversions to SI live in :mod:`arm_driver.dynamixel.units`.
"""

from __future__ import annotations

import enum
import itertools
import struct
from collections.abc import Sequence
from dataclasses import dataclass

from arm_driver.dynamixel.instructions import decode_int, decode_uint, encode_int, encode_uint

__all__ = [
    "BAUD_RATE",
    "BAUD_RATES",
    "BUS_WATCHDOG",
    "BUS_WATCHDOG_MAX",
    "BUS_WATCHDOG_TRIPPED",
    "BUS_WATCHDOG_UNIT_S",
    "CONTROL_TABLE",
    "CURRENT_LIMIT",
    "DRIVE_MODE",
    "FIRMWARE_VERSION",
    "GOAL_CURRENT",
    "GOAL_POSITION",
    "GOAL_VELOCITY",
    "HARDWARE_ERROR_STATUS",
    "HOMING_OFFSET",
    "ID",
    "LED",
    "MAX_POSITION_LIMIT",
    "MAX_VOLTAGE_LIMIT",
    "MIN_POSITION_LIMIT",
    "MIN_VOLTAGE_LIMIT",
    "MODEL_NUMBER",
    "MOVING",
    "OPERATING_MODE",
    "PRESENT_CURRENT",
    "PRESENT_INPUT_VOLTAGE",
    "PRESENT_POSITION",
    "PRESENT_TEMPERATURE",
    "PRESENT_VELOCITY",
    "PROFILE_ACCELERATION",
    "PROFILE_VELOCITY",
    "PROFILE_VELOCITY_MAX",
    "REALTIME_TICK",
    "RETURN_DELAY_TIME",
    "SHUTDOWN",
    "STATUS_RETURN_LEVEL",
    "TEMPERATURE_LIMIT",
    "TORQUE_ENABLE",
    "VELOCITY_LIMIT",
    "XM430_W350_MODEL_NUMBER",
    "Access",
    "Area",
    "ControlTableEntry",
    "DriveMode",
    "OperatingMode",
    "StatusReturnLevel",
    "block_struct",
]

XM430_W350_MODEL_NUMBER = 1020
"""Model Number(0) of the XM430-W350 (e-Manual, default value of address 0)."""


class Access(enum.Enum):
    """Whether the host may write an entry."""

    R = "R"
    RW = "RW"


class Area(enum.Enum):
    """Where an entry lives: EEPROM (kept at power-off, torque must be off to write) or RAM."""

    EEPROM = "EEPROM"
    RAM = "RAM"


class OperatingMode(enum.IntEnum):
    """Values of Operating Mode(11)."""

    CURRENT = 0
    VELOCITY = 1
    POSITION = 3
    EXTENDED_POSITION = 4
    CURRENT_BASED_POSITION = 5
    PWM = 16


class StatusReturnLevel(enum.IntEnum):
    """Values of Status Return Level(68): which instructions get a status packet."""

    PING_ONLY = 0
    PING_READ = 1
    ALL = 2


class DriveMode(enum.IntFlag):
    """Bits of Drive Mode(10)."""

    REVERSE = 0x01
    """Reverse mode: CCW negative (Goal/Present Position inverted)."""
    TIME_BASED_PROFILE = 0x04
    """Profile Velocity/Acceleration are times [ms] instead of rates (firmware >= 42)."""
    TORQUE_ON_BY_GOAL_UPDATE = 0x08
    """A goal write turns torque on (firmware >= 45)."""


BAUD_RATES = {
    0: 9_600,
    1: 57_600,
    2: 115_200,
    3: 1_000_000,
    4: 2_000_000,
    5: 3_000_000,
    6: 4_000_000,
    7: 4_500_000,
}
"""Baud Rate(8) value -> line rate [bit/s] (factory value 1: 57,600)."""
BUS_WATCHDOG_TRIPPED = -1
"""Bus Watchdog(98) after the watchdog tripped (Bus Watchdog Error); 0 clears it."""
BUS_WATCHDOG_MAX = 127
"""Largest Bus Watchdog(98) timeout [20 ms]: 2.54 s."""
BUS_WATCHDOG_UNIT_S = 0.020
"""One count of Bus Watchdog(98) [s]."""
PROFILE_VELOCITY_MAX = 32767
"""Largest Profile Velocity(112) [0.229 rev/min] (e-Manual: 0 ~ 32,767; 0 is infinite)."""


@dataclass(frozen=True)
class ControlTableEntry:
    """One control-table item.

    Attributes
    ----------
    name
        Name as in the e-Manual.
    address
        Address [byte offset].
    size
        Size [bytes]: 1, 2 or 4.
    access
        :class:`Access` (R or RW).
    area
        :class:`Area` (EEPROM or RAM).
    signed
        Two's-complement signed value.
    unit
        Unit of one raw count, as the e-Manual gives it ("" when the value is a code).
    """

    name: str
    address: int
    size: int
    access: Access
    area: Area
    signed: bool = False
    unit: str = ""

    @property
    def end(self) -> int:
        """First address after this entry."""
        return self.address + self.size

    def encode(self, value: int) -> bytes:
        """Raw value -> bytes for a Write (range-checked for the size and signedness)."""
        if self.access is not Access.RW:
            raise ValueError(f"{self.name}({self.address}) is read-only")
        return encode_int(value, self.size) if self.signed else encode_uint(value, self.size)

    def decode(self, data: bytes) -> int:
        """Bytes read from the servo -> raw value."""
        if len(data) != self.size:
            raise ValueError(f"{self.name}({self.address}) is {self.size} bytes, got {len(data)}")
        return decode_int(data) if self.signed else decode_uint(data)


_R, _RW, _E, _M = Access.R, Access.RW, Area.EEPROM, Area.RAM
_PULSE = "1 pulse (4096 per rev, 0.088 deg)"
_RPM = "0.229 rev/min"
_MA = "2.69 mA"

MODEL_NUMBER = ControlTableEntry("Model Number", 0, 2, _R, _E)
FIRMWARE_VERSION = ControlTableEntry("Firmware Version", 6, 1, _R, _E)
ID = ControlTableEntry("ID", 7, 1, _RW, _E)
BAUD_RATE = ControlTableEntry("Baud Rate", 8, 1, _RW, _E)
RETURN_DELAY_TIME = ControlTableEntry("Return Delay Time", 9, 1, _RW, _E, unit="2 us")
DRIVE_MODE = ControlTableEntry("Drive Mode", 10, 1, _RW, _E)
OPERATING_MODE = ControlTableEntry("Operating Mode", 11, 1, _RW, _E)
HOMING_OFFSET = ControlTableEntry("Homing Offset", 20, 4, _RW, _E, signed=True, unit=_PULSE)
TEMPERATURE_LIMIT = ControlTableEntry("Temperature Limit", 31, 1, _RW, _E, unit="1 degC")
MAX_VOLTAGE_LIMIT = ControlTableEntry("Max Voltage Limit", 32, 2, _RW, _E, unit="0.1 V")
MIN_VOLTAGE_LIMIT = ControlTableEntry("Min Voltage Limit", 34, 2, _RW, _E, unit="0.1 V")
CURRENT_LIMIT = ControlTableEntry("Current Limit", 38, 2, _RW, _E, unit=_MA)
VELOCITY_LIMIT = ControlTableEntry("Velocity Limit", 44, 4, _RW, _E, unit=_RPM)
MAX_POSITION_LIMIT = ControlTableEntry("Max Position Limit", 48, 4, _RW, _E, unit=_PULSE)
MIN_POSITION_LIMIT = ControlTableEntry("Min Position Limit", 52, 4, _RW, _E, unit=_PULSE)
SHUTDOWN = ControlTableEntry("Shutdown", 63, 1, _RW, _E)
TORQUE_ENABLE = ControlTableEntry("Torque Enable", 64, 1, _RW, _M)
LED = ControlTableEntry("LED", 65, 1, _RW, _M)
STATUS_RETURN_LEVEL = ControlTableEntry("Status Return Level", 68, 1, _RW, _M)
HARDWARE_ERROR_STATUS = ControlTableEntry("Hardware Error Status", 70, 1, _R, _M)
BUS_WATCHDOG = ControlTableEntry("Bus Watchdog", 98, 1, _RW, _M, signed=True, unit="20 ms")
GOAL_CURRENT = ControlTableEntry("Goal Current", 102, 2, _RW, _M, signed=True, unit=_MA)
GOAL_VELOCITY = ControlTableEntry("Goal Velocity", 104, 4, _RW, _M, signed=True, unit=_RPM)
PROFILE_ACCELERATION = ControlTableEntry(
    "Profile Acceleration", 108, 4, _RW, _M, unit="214.577 rev/min^2"
)
PROFILE_VELOCITY = ControlTableEntry("Profile Velocity", 112, 4, _RW, _M, unit=_RPM)
GOAL_POSITION = ControlTableEntry("Goal Position", 116, 4, _RW, _M, signed=True, unit=_PULSE)
REALTIME_TICK = ControlTableEntry("Realtime Tick", 120, 2, _R, _M, unit="1 ms")
MOVING = ControlTableEntry("Moving", 122, 1, _R, _M)
PRESENT_CURRENT = ControlTableEntry("Present Current", 126, 2, _R, _M, signed=True, unit=_MA)
PRESENT_VELOCITY = ControlTableEntry("Present Velocity", 128, 4, _R, _M, signed=True, unit=_RPM)
PRESENT_POSITION = ControlTableEntry("Present Position", 132, 4, _R, _M, signed=True, unit=_PULSE)
PRESENT_INPUT_VOLTAGE = ControlTableEntry("Present Input Voltage", 144, 2, _R, _M, unit="0.1 V")
PRESENT_TEMPERATURE = ControlTableEntry("Present Temperature", 146, 1, _R, _M, unit="1 degC")

CONTROL_TABLE: tuple[ControlTableEntry, ...] = (
    MODEL_NUMBER,
    FIRMWARE_VERSION,
    ID,
    BAUD_RATE,
    RETURN_DELAY_TIME,
    DRIVE_MODE,
    OPERATING_MODE,
    HOMING_OFFSET,
    TEMPERATURE_LIMIT,
    MAX_VOLTAGE_LIMIT,
    MIN_VOLTAGE_LIMIT,
    CURRENT_LIMIT,
    VELOCITY_LIMIT,
    MAX_POSITION_LIMIT,
    MIN_POSITION_LIMIT,
    SHUTDOWN,
    TORQUE_ENABLE,
    LED,
    STATUS_RETURN_LEVEL,
    HARDWARE_ERROR_STATUS,
    BUS_WATCHDOG,
    GOAL_CURRENT,
    GOAL_VELOCITY,
    PROFILE_ACCELERATION,
    PROFILE_VELOCITY,
    GOAL_POSITION,
    REALTIME_TICK,
    MOVING,
    PRESENT_CURRENT,
    PRESENT_VELOCITY,
    PRESENT_POSITION,
    PRESENT_INPUT_VOLTAGE,
    PRESENT_TEMPERATURE,
)
"""Every entry above, in address order."""


_STRUCT_CODES = {1: "B", 2: "H", 4: "I"}


def block_struct(entries: Sequence[ControlTableEntry]) -> struct.Struct:
    """The decoder of consecutive entries read in one go (a Read or Sync Read of their
    whole range): its ``unpack`` gives their raw values in address order, each as the
    entry's :meth:`~ControlTableEntry.decode` gives it.

    Raises
    ------
    ValueError
        No entry, or entries that do not follow one another without a gap.
    """
    if not entries:
        raise ValueError("no control-table entry given")
    for before, after in itertools.pairwise(entries):
        if after.address != before.end:
            raise ValueError(f"{after.name}({after.address}) does not follow {before.name}")
    codes = (_STRUCT_CODES[e.size].lower() if e.signed else _STRUCT_CODES[e.size] for e in entries)
    return struct.Struct("<" + "".join(codes))

"""Tests of arm_driver.dynamixel.control_table against the e-Manual's XM430-W350 tables.

The rows below are copied from the ROBOTIS e-Manual XM430-W350 page, "Control Table of
EEPROM Area" / "Control Table of RAM Area" (address, size in bytes, access, unit).
"""

from __future__ import annotations

import itertools

import pytest

from arm_driver.dynamixel import control_table as ct
from arm_driver.dynamixel.control_table import (
    BAUD_RATES,
    CONTROL_TABLE,
    Access,
    Area,
    DriveMode,
    OperatingMode,
    StatusReturnLevel,
)
from arm_driver.errors import HardwareErrorStatus

EMANUAL_ROWS = [
    # name, address, size, access, unit
    ("Model Number", 0, 2, "R", ""),
    ("Firmware Version", 6, 1, "R", ""),
    ("ID", 7, 1, "RW", ""),
    ("Baud Rate", 8, 1, "RW", ""),
    ("Return Delay Time", 9, 1, "RW", "2 us"),
    ("Drive Mode", 10, 1, "RW", ""),
    ("Operating Mode", 11, 1, "RW", ""),
    ("Homing Offset", 20, 4, "RW", "pulse"),
    ("Temperature Limit", 31, 1, "RW", "degC"),
    ("Max Voltage Limit", 32, 2, "RW", "0.1 V"),
    ("Min Voltage Limit", 34, 2, "RW", "0.1 V"),
    ("Current Limit", 38, 2, "RW", "2.69 mA"),
    ("Velocity Limit", 44, 4, "RW", "0.229 rev/min"),
    ("Max Position Limit", 48, 4, "RW", "pulse"),
    ("Min Position Limit", 52, 4, "RW", "pulse"),
    ("Shutdown", 63, 1, "RW", ""),
    ("Torque Enable", 64, 1, "RW", ""),
    ("LED", 65, 1, "RW", ""),
    ("Status Return Level", 68, 1, "RW", ""),
    ("Hardware Error Status", 70, 1, "R", ""),
    ("Bus Watchdog", 98, 1, "RW", "20 ms"),
    ("Goal Current", 102, 2, "RW", "2.69 mA"),
    ("Goal Velocity", 104, 4, "RW", "0.229 rev/min"),
    ("Profile Acceleration", 108, 4, "RW", "214.577 rev/min^2"),
    ("Profile Velocity", 112, 4, "RW", "0.229 rev/min"),
    ("Goal Position", 116, 4, "RW", "pulse"),
    ("Realtime Tick", 120, 2, "R", "1 ms"),
    ("Moving", 122, 1, "R", ""),
    ("Present Current", 126, 2, "R", "2.69 mA"),
    ("Present Velocity", 128, 4, "R", "0.229 rev/min"),
    ("Present Position", 132, 4, "R", "pulse"),
    ("Present Input Voltage", 144, 2, "R", "0.1 V"),
    ("Present Temperature", 146, 1, "R", "degC"),
]
SIGNED = {
    "Bus Watchdog",  # reads -1 after it tripped
    "Homing Offset",
    "Goal Current",
    "Goal Velocity",
    "Goal Position",
    "Present Current",
    "Present Velocity",
    "Present Position",
}


@pytest.mark.parametrize(("name", "address", "size", "access", "unit"), EMANUAL_ROWS)
def test_entries_match_the_emanual(
    name: str, address: int, size: int, access: str, unit: str
) -> None:
    entry = getattr(ct, name.upper().replace(" ", "_"))
    assert entry in CONTROL_TABLE
    assert (entry.name, entry.address, entry.size) == (name, address, size)
    assert entry.access is Access(access)
    assert entry.area is (Area.EEPROM if address < 64 else Area.RAM)
    assert entry.signed == (name in SIGNED)
    assert unit in entry.unit


def test_table_is_complete_sorted_and_without_overlaps() -> None:
    assert len(CONTROL_TABLE) == len(EMANUAL_ROWS)
    for before, after in itertools.pairwise(CONTROL_TABLE):
        assert before.end <= after.address
    for entry in CONTROL_TABLE:
        assert entry.name.upper().replace(" ", "_") in ct.__all__


def test_entry_encode_decode() -> None:
    assert ct.GOAL_CURRENT.encode(-100) == (-100).to_bytes(2, "little", signed=True)
    assert ct.PRESENT_POSITION.decode(b"\xff\xff\xff\xff") == -1
    assert ct.PRESENT_INPUT_VOLTAGE.decode(b"\x77\x00") == 119
    assert ct.TORQUE_ENABLE.encode(1) == b"\x01"
    assert ct.BUS_WATCHDOG.decode(b"\xff") == ct.BUS_WATCHDOG_TRIPPED
    with pytest.raises(ValueError, match="does not fit"):
        ct.GOAL_CURRENT.encode(40_000)
    with pytest.raises(ValueError, match="does not fit"):
        ct.PROFILE_VELOCITY.encode(-1)
    with pytest.raises(ValueError, match=r"Present Position\(132\) is read-only"):
        ct.PRESENT_POSITION.encode(0)
    with pytest.raises(ValueError, match="is 4 bytes, got 2"):
        ct.PRESENT_POSITION.decode(b"\x00\x00")


def test_codes() -> None:
    assert [int(mode) for mode in OperatingMode] == [0, 1, 3, 4, 5, 16]
    assert [int(level) for level in StatusReturnLevel] == [0, 1, 2]
    assert BAUD_RATES[1] == 57_600 and BAUD_RATES[3] == 1_000_000 and len(BAUD_RATES) == 8
    assert DriveMode(0x05) == DriveMode.REVERSE | DriveMode.TIME_BASED_PROFILE
    assert ct.XM430_W350_MODEL_NUMBER == 1020


def test_shutdown_factory_value_uses_the_hardware_error_bits() -> None:
    """Shutdown(63) has the Hardware Error Status(70) layout; its factory value is 52."""
    assert HardwareErrorStatus(52) == (
        HardwareErrorStatus.OVERHEATING
        | HardwareErrorStatus.ELECTRICAL_SHOCK
        | HardwareErrorStatus.OVERLOAD
    )


def test_block_struct_decodes_as_each_entry() -> None:
    entries = (ct.PRESENT_CURRENT, ct.PRESENT_VELOCITY, ct.PRESENT_POSITION)
    block = ct.block_struct(entries)
    assert block.size == ct.PRESENT_POSITION.end - ct.PRESENT_CURRENT.address
    samples = (bytes(range(10)), b"\xff" * 10, b"\x00\x80" + b"\xff\xff\xff\x7f" + b"\x00" * 4)
    for data in samples:
        offsets = [e.address - ct.PRESENT_CURRENT.address for e in entries]
        expected = tuple(
            e.decode(data[o : o + e.size]) for e, o in zip(entries, offsets, strict=True)
        )
        assert block.unpack(data) == expected
    unsigned = ct.block_struct((ct.TORQUE_ENABLE, ct.LED))
    assert unsigned.unpack(b"\x01\xff") == (1, 255)


def test_block_struct_refuses_a_gap() -> None:
    with pytest.raises(ValueError, match="does not follow"):
        ct.block_struct((ct.PRESENT_CURRENT, ct.PRESENT_POSITION))
    with pytest.raises(ValueError, match="no control-table entry"):
        ct.block_struct(())

"""Tests of arm_driver.errors: one tree, clear messages, decoded hardware bits."""

from __future__ import annotations

import pickle

import pytest

from arm_driver.errors import (
    ArmDriverError,
    BusTimeoutError,
    CommunicationError,
    CrcError,
    HardwareError,
    HardwareErrorStatus,
    InstructionError,
    LimitError,
    StatusError,
)

EXAMPLES = [
    BusTimeoutError(3, 0.012, received_bytes=5),
    BusTimeoutError(None, 0.05),
    CommunicationError("malformed packet", servo_id=1),
    CrcError(0x1234, 0xABCD, servo_id=1),
    InstructionError(2, StatusError.DATA_LIMIT),
    HardwareError(2, HardwareErrorStatus.OVERHEATING | HardwareErrorStatus.OVERLOAD),
    HardwareError(2),
    LimitError("elbow", 3.2, -1.5, 1.5, servo_id=2),
]


@pytest.mark.parametrize("error", EXAMPLES, ids=lambda e: type(e).__name__)
def test_one_tree_and_pickling(error: ArmDriverError) -> None:
    assert isinstance(error, ArmDriverError)
    copy = pickle.loads(pickle.dumps(error))
    assert type(copy) is type(error)
    assert str(copy) == str(error)
    assert copy.__dict__ == error.__dict__


def test_builtin_bases() -> None:
    assert isinstance(BusTimeoutError(1, 0.01), TimeoutError)
    assert isinstance(LimitError("j", 1.0, 0.0, 0.5), ValueError)
    assert issubclass(CrcError, CommunicationError)


def test_messages_name_the_servo_and_what_happened() -> None:
    assert str(BusTimeoutError(3, 0.012, received_bytes=5)) == (
        "servo 3: no complete status packet within 12.0 ms (only 5 byte(s) of it received)"
    )
    assert "nothing received" in str(BusTimeoutError(3, 0.012))
    assert str(CrcError(0x1234, 0xABCD, servo_id=1)).startswith(
        "servo 1: CRC mismatch, frame carries 0xABCD but its bytes give 0x1234"
    )
    assert str(InstructionError(2, 6)).startswith(
        "servo 2 rejected the instruction, error 0x06: Data Limit Error"
    )
    message = str(HardwareError(5, HardwareErrorStatus(0x24)))
    assert message.startswith(
        "servo 5: hardware error (Alert bit set): Hardware Error Status 0x24: "
        "Overheating Error, Overload Error."
    )
    assert "REBOOT" in message
    assert "not read yet" in str(HardwareError(5))
    assert str(LimitError("elbow", 3.2, -1.5, 1.5, servo_id=2)) == (
        "joint 'elbow' (servo 2): command 3.2 rad is outside its limits [-1.5, 1.5] rad; "
        "nothing was sent"
    )


def test_status_error_values_and_descriptions() -> None:
    """e-Manual, Protocol 2.0, Status Packet -> Error: numbers 0x01-0x07."""
    assert [(e.name, int(e)) for e in StatusError] == [
        ("RESULT_FAIL", 1),
        ("INSTRUCTION", 2),
        ("CRC", 3),
        ("DATA_RANGE", 4),
        ("DATA_LENGTH", 5),
        ("DATA_LIMIT", 6),
        ("ACCESS", 7),
    ]
    assert all(error.description for error in StatusError)


def test_hardware_error_bits() -> None:
    """e-Manual, XM430-W350, Hardware Error Status(70): bits 0, 2, 3, 4, 5."""
    assert [(bit.name, int(bit)) for bit in HardwareErrorStatus] == [
        ("INPUT_VOLTAGE", 0x01),
        ("OVERHEATING", 0x04),
        ("MOTOR_ENCODER", 0x08),
        ("ELECTRICAL_SHOCK", 0x10),
        ("OVERLOAD", 0x20),
    ]
    assert HardwareErrorStatus(0x3D).describe() == (
        "Input Voltage Error, Overheating Error, Motor Encoder Error, "
        "Electrical Shock Error, Overload Error"
    )
    assert HardwareErrorStatus(0x82).describe() == "unknown bits 0x82"
    assert HardwareErrorStatus(0).describe() == "no bit set"
    assert int(HardwareError(1, HardwareErrorStatus(0x82)).status) == 0x82

"""Tests of arm_driver.dynamixel.protocol: CRC-16, byte stuffing, packets, status errors.

Example packets are copied byte for byte from the ROBOTIS e-Manual, "DYNAMIXEL Protocol
2.0", Instruction Details (ROBOTIS-GIT/emanual ``docs/en/dxl/protocol2.md``); the CRC
table is checked against DynamixelSDK ``protocol2_packet_handler.py`` (``updateCRC``).
"""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from arm_driver.dynamixel import (
    BROADCAST_ID,
    HEADER,
    Instruction,
    InstructionPacket,
    StatusPacket,
    check_status,
    crc16,
    decode_instruction,
    decode_packet,
    decode_status,
    encode_instruction,
    encode_status,
    stuff,
    unstuff,
)
from arm_driver.errors import (
    CommunicationError,
    CrcError,
    HardwareError,
    InstructionError,
    StatusError,
)


def h(text: str) -> bytes:
    """Bytes from the e-Manual's hex notation, e.g. ``"FF FF FD 00"``."""
    return bytes.fromhex(text)


# (instruction: servo id, instruction code, parameters, packet) from the e-Manual.
EMANUAL_INSTRUCTIONS = {
    "ping": (1, 0x01, "", "FF FF FD 00 01 03 00 01 19 4E"),
    "ping broadcast": (0xFE, 0x01, "", "FF FF FD 00 FE 03 00 01 31 42"),
    "read present position": (
        1,
        0x02,
        "84 00 04 00",
        "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15",
    ),
    "write goal position 512": (
        1,
        0x03,
        "74 00 00 02 00 00",
        "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89",
    ),
    "reg write goal velocity 200": (
        1,
        0x04,
        "68 00 C8 00 00 00",
        "FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E",
    ),
    "action": (1, 0x05, "", "FF FF FD 00 01 03 00 05 02 CE"),
    "factory reset except id": (1, 0x06, "01", "FF FF FD 00 01 04 00 06 01 A1 E6"),
    "reboot": (1, 0x08, "", "FF FF FD 00 01 03 00 08 2F 4E"),
    "clear multi-turn": (
        1,
        0x10,
        "01 44 58 4C 22",
        "FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC",
    ),
    "sync read present position of 1, 2": (
        0xFE,
        0x82,
        "84 00 04 00 01 02",
        "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA",
    ),
    "sync write goal position 150, 170": (
        0xFE,
        0x83,
        "74 00 04 00 01 96 00 00 00 02 AA 00 00 00",
        "FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87",
    ),
    "bulk read voltage of 1, temperature of 2": (
        0xFE,
        0x92,
        "01 90 00 02 00 02 92 00 01 00",
        "FF FF FD 00 FE 0D 00 92 01 90 00 02 00 02 92 00 01 00 1A 05",
    ),
    "bulk write voltage limit of 1, temperature limit of 2": (
        0xFE,
        0x93,
        "01 20 00 02 00 A0 00 02 1F 00 01 00 50",
        "FF FF FD 00 FE 10 00 93 01 20 00 02 00 A0 00 02 1F 00 01 00 50 B7 68",
    ),
}

# (status: servo id, error byte parameters, packet) from the e-Manual.
EMANUAL_STATUSES = {
    "ping reply id 1": (1, "06 04 26", "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D"),
    "ping reply id 2": (2, "06 04 26", "FF FF FD 00 02 07 00 55 00 06 04 26 6F 6D"),
    "read reply 166": (1, "A6 00 00 00", "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0"),
    "sync read reply 2079": (
        2,
        "1F 08 00 00",
        "FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE",
    ),
    "write reply": (1, "", "FF FF FD 00 01 04 00 55 00 A1 0C"),
    "bulk read reply 119": (1, "77 00", "FF FF FD 00 01 06 00 55 00 77 00 C3 69"),
    "bulk read reply 36": (2, "24", "FF FF FD 00 02 05 00 55 00 24 8B A9"),
}

ids = st.one_of(st.integers(0, 252), st.just(BROADCAST_ID))
instructions = st.integers(0, 255).filter(lambda code: code != 0x55)
# Parameters built from pieces that exercise stuffing: the pattern itself, its parts
# and random bytes.
params = st.lists(
    st.one_of(
        st.sampled_from([b"\xff\xff\xfd", b"\xff\xff\xfd\xfd", b"\xff", b"\xfd", b"\x00"]),
        st.binary(max_size=8),
    ),
    max_size=12,
).map(b"".join)


# --- CRC-16 -----------------------------------------------------------------------------


def test_crc16_table_matches_dynamixel_sdk() -> None:
    """GIVEN single bytes WHEN checksummed THEN the SDK's table entries come out."""
    sdk_first = [0x0000, 0x8005, 0x800F, 0x000A, 0x801B, 0x001E, 0x0014, 0x8011]
    assert [crc16(bytes((byte,))) for byte in range(8)] == sdk_first
    assert crc16(b"\xff") == 0x0202  # the SDK table's last entry


def test_crc16_standard_check_value() -> None:
    """Polynomial 0x8005, init 0, no reflection is CRC-16/BUYPASS: check value 0xFEE8."""
    assert crc16(b"123456789") == 0xFEE8


@given(st.binary(max_size=64), st.binary(max_size=64))
def test_crc16_continues_from_a_running_value(a: bytes, b: bytes) -> None:
    assert crc16(b, crc16(a)) == crc16(a + b)


# --- byte stuffing ----------------------------------------------------------------------


def test_stuffing_examples() -> None:
    assert stuff(h("FF FF FD")) == h("FF FF FD FD")
    assert stuff(h("FF FF FD FD")) == h("FF FF FD FD FD")
    assert stuff(h("FF FF FF FD 00 FF FF FD")) == h("FF FF FF FD FD 00 FF FF FD FD")
    assert stuff(h("FF FD FF FD")) == h("FF FD FF FD")
    assert unstuff(h("FF FF FD FD FD")) == h("FF FF FD FD")


@given(params)
def test_unstuff_inverts_stuff(data: bytes) -> None:
    stuffed = stuff(data)
    assert unstuff(stuffed) == data
    assert len(stuffed) == len(data) + data.count(b"\xff\xff\xfd")
    # No header can appear inside stuffed data: every FF FF FD is followed by FD.
    assert stuffed.count(b"\xff\xff\xfd") == stuffed.count(b"\xff\xff\xfd\xfd")


@given(params)
def test_stuff_inverts_unstuff_on_valid_data(data: bytes) -> None:
    stuffed = stuff(data)
    assert stuff(unstuff(stuffed)) == stuffed


@pytest.mark.parametrize("data", ["FF FF FD", "00 FF FF FD 00", "FF FF FD 01 FF FF FD FD"])
def test_unstuff_rejects_a_pattern_without_its_stuffing_byte(data: str) -> None:
    with pytest.raises(CommunicationError, match="stuffing"):
        unstuff(h(data))


# --- e-Manual example packets -----------------------------------------------------------


@pytest.mark.parametrize("name", list(EMANUAL_INSTRUCTIONS))
def test_instruction_packets_match_the_emanual(name: str) -> None:
    servo_id, code, parameters, packet = EMANUAL_INSTRUCTIONS[name]
    assert encode_instruction(servo_id, code, h(parameters)) == h(packet)
    assert decode_instruction(h(packet)) == InstructionPacket(servo_id, code, h(parameters))


@pytest.mark.parametrize("name", list(EMANUAL_STATUSES))
def test_status_packets_match_the_emanual(name: str) -> None:
    servo_id, parameters, packet = EMANUAL_STATUSES[name]
    status = decode_status(h(packet))
    assert status == StatusPacket(servo_id, 0, False, h(parameters))
    assert encode_status(servo_id, 0, h(parameters)) == h(packet)
    assert check_status(status) is status


def test_stuffed_packet_length_counts_the_stuffing_byte() -> None:
    """Length and CRC are computed after stuffing (e-Manual, Processing Order of Transmission)."""
    packet = encode_instruction(1, Instruction.WRITE, h("74 00 FF FF FD 00"))
    assert packet[5:7] == (3 + 7).to_bytes(2, "little")
    assert packet[7:-2] == h("03 74 00 FF FF FD FD 00")
    assert crc16(packet[:-2]) == int.from_bytes(packet[-2:], "little")
    assert decode_instruction(packet).params == h("74 00 FF FF FD 00")


# --- round trips ------------------------------------------------------------------------


@given(ids, instructions, params)
def test_instruction_round_trip(servo_id: int, code: int, data: bytes) -> None:
    packet = encode_instruction(servo_id, code, data)
    assert packet.startswith(HEADER)
    assert decode_instruction(packet) == InstructionPacket(servo_id, code, data)
    assert decode_packet(packet) == InstructionPacket(servo_id, code, data)


@given(st.integers(0, 252), st.integers(0, 127), st.booleans(), params)
def test_status_round_trip(servo_id: int, error: int, alert: bool, data: bytes) -> None:
    packet = encode_status(servo_id, error, data, alert=alert)
    assert decode_status(packet) == StatusPacket(servo_id, error, alert, data)
    assert decode_packet(packet) == StatusPacket(servo_id, error, alert, data)


@given(
    st.one_of(
        st.builds(encode_instruction, ids, instructions, params),
        st.builds(encode_status, st.integers(0, 252), st.integers(0, 127), params),
    ),
    st.data(),
)
def test_any_single_flipped_bit_is_rejected(packet: bytes, data: st.DataObject) -> None:
    """A damaged packet is never accepted, neither as itself nor as another packet."""
    bit = data.draw(st.integers(0, 8 * len(packet) - 1), label="bit")
    damaged = bytearray(packet)
    damaged[bit // 8] ^= 1 << (bit % 8)
    with pytest.raises(CommunicationError):
        decode_packet(bytes(damaged))


# --- malformed input --------------------------------------------------------------------


def test_decode_errors_name_the_fault() -> None:
    good = h("FF FF FD 00 01 04 00 55 00 A1 0C")
    with pytest.raises(CommunicationError, match="too short"):
        decode_status(good[:9])
    with pytest.raises(CommunicationError, match="bad header"):
        decode_status(b"\xff\xff\xfe" + good[3:])
    with pytest.raises(CommunicationError, match="length field 4 needs 11 bytes, got 12"):
        decode_status(good + b"\x00")
    with pytest.raises(CrcError, match="CRC mismatch") as crc_error:
        decode_status(good[:-1] + b"\x0d")
    assert crc_error.value.servo_id == 1
    assert (crc_error.value.received, crc_error.value.computed) == (0x0DA1, 0x0CA1)
    with pytest.raises(CommunicationError, match="expected a status packet"):
        decode_status(encode_instruction(1, Instruction.PING))
    with pytest.raises(CommunicationError, match="expected an instruction packet"):
        decode_instruction(good)


def test_ids_that_are_never_used_are_rejected() -> None:
    """253 and 255 are not ids (e-Manual, Packet ID); a status never comes from 254."""
    for servo_id in (0xFD, 0xFF):
        frame = bytearray(encode_instruction(1, Instruction.PING))
        frame[4] = servo_id
        frame[-2:] = crc16(frame[:-2]).to_bytes(2, "little")
        with pytest.raises(CommunicationError, match="invalid id"):
            decode_packet(bytes(frame))
    frame = bytearray(encode_status(1))
    frame[4] = BROADCAST_ID
    frame[-2:] = crc16(frame[:-2]).to_bytes(2, "little")
    with pytest.raises(CommunicationError, match="invalid id 254"):
        decode_status(bytes(frame))


def test_bad_arguments_raise_value_error() -> None:
    with pytest.raises(ValueError, match="servo id 253"):
        encode_instruction(253, Instruction.PING)
    with pytest.raises(ValueError, match="not an instruction"):
        encode_instruction(1, 0x55)
    with pytest.raises(ValueError, match="servo id 254"):
        encode_status(BROADCAST_ID)
    with pytest.raises(ValueError, match="error number 128"):
        encode_status(1, 0x80)
    with pytest.raises(ValueError, match="too long"):
        encode_instruction(1, Instruction.WRITE, bytes(0xFFFF))


# --- status error byte -> typed exceptions ----------------------------------------------


@pytest.mark.parametrize("error", list(StatusError))
def test_error_number_raises_instruction_error(error: StatusError) -> None:
    status = decode_status(encode_status(7, error))
    assert status.error == error and not status.alert
    with pytest.raises(InstructionError) as raised:
        check_status(status)
    assert raised.value.servo_id == 7
    assert raised.value.error is error
    assert raised.value.error_number == int(error)
    assert "servo 7" in str(raised.value) and error.description in str(raised.value)


def test_undefined_error_number_still_raises() -> None:
    with pytest.raises(InstructionError, match="does not define") as raised:
        check_status(StatusPacket(3, 0x2A))
    assert raised.value.error is None and raised.value.error_number == 0x2A


def test_alert_bit_raises_hardware_error() -> None:
    packet = encode_status(4, 0, h("A6 00 00 00"), alert=True)
    assert packet[8] == 0x80  # the error byte
    status = decode_status(packet)
    assert status.alert and status.error == 0
    with pytest.raises(HardwareError, match="servo 4: hardware error") as raised:
        check_status(status)
    assert raised.value.servo_id == 4 and raised.value.status is None
    assert check_status(status, ignore_alert=True) is status


def test_alert_with_an_error_number_reports_both() -> None:
    status = decode_status(encode_status(4, StatusError.DATA_RANGE, alert=True))
    with pytest.raises(HardwareError, match="also carried error 0x04") as raised:
        check_status(status)
    assert raised.value.error_number == StatusError.DATA_RANGE
    with pytest.raises(InstructionError):
        check_status(status, ignore_alert=True)

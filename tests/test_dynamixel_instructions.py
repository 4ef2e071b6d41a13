"""Tests of arm_driver.dynamixel.instructions: builders, reply parsers, field helpers.

Expected bytes are the e-Manual's examples ("DYNAMIXEL Protocol 2.0", Instruction
Details), built here through the named builders rather than raw instruction codes.
"""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from arm_driver.dynamixel import (
    BROADCAST_ID,
    PingReply,
    StatusPacket,
    SyncWriteFrame,
    decode_int,
    decode_status,
    decode_uint,
    encode_int,
    encode_ping,
    encode_read,
    encode_reboot,
    encode_status,
    encode_sync_read,
    encode_sync_write,
    encode_uint,
    encode_write,
    parse_ping_reply,
    parse_read_reply,
    parse_sync_read_replies,
    parse_write_reply,
)
from arm_driver.dynamixel.control_table import GOAL_CURRENT, GOAL_POSITION, PRESENT_POSITION
from arm_driver.errors import CommunicationError, HardwareError, InstructionError, StatusError


def h(text: str) -> bytes:
    return bytes.fromhex(text)


# --- builders against the e-Manual ------------------------------------------------------


def test_ping() -> None:
    assert encode_ping(1) == h("FF FF FD 00 01 03 00 01 19 4E")
    assert encode_ping(BROADCAST_ID) == h("FF FF FD 00 FE 03 00 01 31 42")


def test_read_present_position() -> None:
    packet = encode_read(1, PRESENT_POSITION.address, PRESENT_POSITION.size)
    assert packet == h("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15")


def test_write_goal_position() -> None:
    packet = encode_write(1, GOAL_POSITION.address, GOAL_POSITION.encode(512))
    assert packet == h("FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89")


def test_reboot() -> None:
    assert encode_reboot(1) == h("FF FF FD 00 01 03 00 08 2F 4E")


def test_sync_read_present_position() -> None:
    packet = encode_sync_read(PRESENT_POSITION.address, PRESENT_POSITION.size, [1, 2])
    assert packet == h("FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA")


def test_sync_write_goal_position() -> None:
    packet = encode_sync_write(
        GOAL_POSITION.address,
        GOAL_POSITION.size,
        {1: GOAL_POSITION.encode(150), 2: GOAL_POSITION.encode(170)},
    )
    assert packet == h("FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87")


@given(
    st.sampled_from([GOAL_CURRENT, GOAL_POSITION]),
    st.lists(st.integers(0, 252), min_size=1, max_size=4, unique=True),
    st.data(),
)
def test_sync_write_frame_is_encode_sync_write(entry, ids: list[int], data: st.DataObject) -> None:
    half = 1 << (8 * entry.size - 1)
    frame = SyncWriteFrame(entry.address, entry.size, ids)
    # Values that need byte stuffing (FF FF FD inside a 4-byte goal) come often.
    value = st.one_of(st.integers(-half, half - 1), st.sampled_from([-1, -3, -131073 % half]))
    for _ in range(20):
        values = [entry.encode(data.draw(value)) for _ in ids]
        assert frame.packet(values) == encode_sync_write(
            entry.address, entry.size, dict(zip(ids, values, strict=True))
        )


def test_sync_write_frame_stuffs_a_goal() -> None:
    frame = SyncWriteFrame(GOAL_POSITION.address, GOAL_POSITION.size, [1, 2])
    values = [GOAL_POSITION.encode(-131073), GOAL_POSITION.encode(5)]
    assert b"\xff\xff\xfd\xfd" in frame.packet(values)
    assert frame.packet(values) == encode_sync_write(116, 4, dict(zip([1, 2], values, strict=True)))


def test_sync_write_frame_argument_errors() -> None:
    frame = SyncWriteFrame(116, 4, [1, 2])
    with pytest.raises(ValueError, match="servo 2: 2 bytes of data, expected 4"):
        frame.packet([bytes(4), bytes(2)])
    with pytest.raises(ValueError, match="1 values for servo ids"):
        frame.packet([bytes(4)])
    with pytest.raises(ValueError, match="duplicate"):
        SyncWriteFrame(116, 4, [1, 1])


def test_builder_argument_errors() -> None:
    with pytest.raises(ValueError, match="servo id 254"):
        encode_read(BROADCAST_ID, 132, 4)
    with pytest.raises(ValueError, match="address 65536"):
        encode_read(1, 0x10000, 4)
    with pytest.raises(ValueError, match="data length 0"):
        encode_write(1, 64, b"")
    with pytest.raises(ValueError, match="duplicate"):
        encode_sync_read(132, 4, [1, 2, 1])
    with pytest.raises(ValueError, match="no servo"):
        encode_sync_read(132, 4, [])
    with pytest.raises(ValueError, match="servo id 254"):
        encode_sync_read(132, 4, [1, BROADCAST_ID])
    with pytest.raises(ValueError, match="servo 2: 2 bytes of data, expected 4"):
        encode_sync_write(116, 4, {1: bytes(4), 2: bytes(2)})


def test_broadcast_write_is_allowed() -> None:
    assert encode_write(BROADCAST_ID, 64, b"\x00")[4] == BROADCAST_ID


# --- reply parsers ----------------------------------------------------------------------


def test_ping_reply_from_the_emanual() -> None:
    status = decode_status(h("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D"))
    assert parse_ping_reply(status, 1) == PingReply(1, 1030, 38)  # XM430-W210, firmware 38
    assert parse_ping_reply(status) == PingReply(1, 1030, 38)  # after a broadcast ping


def test_read_reply_from_the_emanual() -> None:
    status = decode_status(h("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0"))
    data = parse_read_reply(status, 1, PRESENT_POSITION.size)
    assert PRESENT_POSITION.decode(data) == 166


def test_sync_read_replies_from_the_emanual_in_any_order() -> None:
    replies = [
        decode_status(h("FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE")),
        decode_status(h("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0")),
    ]
    data = parse_sync_read_replies(replies, [1, 2], 4)
    assert list(data) == [1, 2]
    assert {key: decode_int(value) for key, value in data.items()} == {1: 166, 2: 2079}


def test_write_reply_from_the_emanual() -> None:
    status = decode_status(h("FF FF FD 00 01 04 00 55 00 A1 0C"))
    assert status == StatusPacket(1, error=0, alert=False, params=b"")
    assert parse_write_reply(status, 1) is None
    with pytest.raises(CommunicationError, match="servo 2: Write reply came from servo 1"):
        parse_write_reply(status, 2)
    with pytest.raises(CommunicationError, match="Write reply carries 1"):
        parse_write_reply(StatusPacket(1, params=b"\x00"), 1)


def test_reply_from_the_wrong_servo_or_of_the_wrong_size() -> None:
    status = StatusPacket(2, params=bytes(4))
    with pytest.raises(CommunicationError, match="servo 1: Read reply came from servo 2"):
        parse_read_reply(status, 1, 4)
    with pytest.raises(CommunicationError, match="4 parameter byte"):
        parse_read_reply(status, 2, 2)
    with pytest.raises(CommunicationError, match="Ping reply carries 4"):
        parse_ping_reply(status)
    with pytest.raises(CommunicationError, match="Write reply carries 4"):
        parse_write_reply(status, 2)


def test_sync_read_reply_problems() -> None:
    one, two, three = (StatusPacket(i, params=bytes(2)) for i in (1, 2, 3))
    with pytest.raises(CommunicationError, match="servo 3, which was not asked"):
        parse_sync_read_replies([one, three], [1, 2], 2)
    with pytest.raises(CommunicationError, match="servo 1: two replies"):
        parse_sync_read_replies([one, one, two], [1, 2], 2)
    with pytest.raises(CommunicationError, match=r"no Sync Read reply from servo\(s\) \[2\]"):
        parse_sync_read_replies([one], [1, 2], 2)
    with pytest.raises(CommunicationError, match="carries 2 parameter"):
        parse_sync_read_replies([one, two], [1, 2], 4)


def test_reply_parsers_raise_the_servo_errors() -> None:
    rejected = decode_status(encode_status(1, StatusError.ACCESS))
    with pytest.raises(InstructionError) as raised:
        parse_write_reply(rejected, 1)
    assert raised.value.error is StatusError.ACCESS
    faulted = decode_status(encode_status(1, 0, b"\x24", alert=True))
    with pytest.raises(HardwareError):
        parse_read_reply(faulted, 1, 1)
    # How the bus reads Hardware Error Status (70) from a faulted servo:
    assert parse_read_reply(faulted, 1, 1, ignore_alert=True) == b"\x24"
    with pytest.raises(HardwareError):
        parse_sync_read_replies([faulted], [1], 1)
    assert parse_sync_read_replies([faulted], [1], 1, ignore_alert=True) == {1: b"\x24"}


# --- field helpers ----------------------------------------------------------------------


@given(st.sampled_from([1, 2, 4]), st.data())
def test_field_round_trips(size: int, data: st.DataObject) -> None:
    unsigned = data.draw(st.integers(0, (1 << (8 * size)) - 1))
    signed = data.draw(st.integers(-(1 << (8 * size - 1)), (1 << (8 * size - 1)) - 1))
    assert decode_uint(encode_uint(unsigned, size)) == unsigned
    assert decode_int(encode_int(signed, size)) == signed
    assert len(encode_uint(unsigned, size)) == len(encode_int(signed, size)) == size


def test_fields_are_little_endian_twos_complement() -> None:
    assert encode_uint(0x0406, 2) == h("06 04")
    assert encode_int(-1, 4) == h("FF FF FF FF")
    assert encode_int(-2079, 4) == h("E1 F7 FF FF")
    assert decode_int(h("00 80")) == -32768
    assert decode_uint(h("00 80")) == 32768


@pytest.mark.parametrize(
    ("function", "value", "size"),
    [
        (encode_uint, 256, 1),
        (encode_uint, -1, 1),
        (encode_uint, 1 << 32, 4),
        (encode_int, 128, 1),
        (encode_int, -129, 1),
        (encode_int, 1 << 31, 4),
        (encode_int, -(1 << 15) - 1, 2),
    ],
)
def test_field_range_errors(function, value: int, size: int) -> None:
    with pytest.raises(ValueError, match=f"does not fit .* {size}-byte field"):
        function(value, size)


def test_field_size_errors() -> None:
    with pytest.raises(ValueError, match="field size 3"):
        encode_uint(0, 3)
    with pytest.raises(ValueError, match="field size 3"):
        decode_int(b"\x00\x00\x00")
    with pytest.raises(ValueError, match="field size 0"):
        decode_uint(b"")

"""Tests of arm_driver.dynamixel.stream: packets out of fragmented, noisy byte streams."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from arm_driver.dynamixel import (
    Instruction,
    InstructionPacket,
    InstructionParser,
    StatusPacket,
    StatusParser,
    crc16,
    encode_instruction,
    encode_status,
)
from arm_driver.errors import CommunicationError, CrcError

# e-Manual, Protocol 2.0, Sync Read example: the replies of servos 1 and 2.
REPLY_1 = bytes.fromhex("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0")
REPLY_2 = bytes.fromhex("FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE")
STATUS_1 = StatusPacket(1, params=bytes.fromhex("A6 00 00 00"))
STATUS_2 = StatusPacket(2, params=bytes.fromhex("1F 08 00 00"))

statuses = st.builds(
    StatusPacket,
    st.integers(0, 252),
    st.integers(0, 127),
    st.booleans(),
    st.lists(st.one_of(st.just(b"\xff\xff\xfd"), st.binary(max_size=6)), max_size=6).map(b"".join),
)
# Line noise without 0xFF cannot contain (part of) a header.
noise = st.binary(max_size=12).map(lambda data: data.replace(b"\xff", b"\x00"))


def encode(packet: StatusPacket) -> bytes:
    return encode_status(packet.servo_id, packet.error, packet.params, alert=packet.alert)


def collect(parser: StatusParser, chunks: list[bytes]) -> list[StatusPacket]:
    packets = []
    for chunk in chunks:
        parser.feed(chunk)
        packets.extend(parser)
    return packets


def test_packets_in_one_chunk_after_garbage() -> None:
    parser = StatusParser()
    parser.feed(b"\x00\x13\xff\xfe" + REPLY_1 + REPLY_2)
    assert list(parser) == [STATUS_1, STATUS_2]
    assert parser.discarded_bytes == 4 and parser.buffered == 0


@pytest.mark.parametrize("split", range(1, len(REPLY_1)))
def test_a_packet_split_anywhere(split: int) -> None:
    parser = StatusParser()
    assert collect(parser, [REPLY_1[:split]]) == []
    assert collect(parser, [REPLY_1[split:]]) == [STATUS_1]


def test_byte_by_byte() -> None:
    stream = b"\xff\xff" + REPLY_1 + b"\xfd" + REPLY_2
    parser = StatusParser()
    assert collect(parser, [bytes((byte,)) for byte in stream]) == [STATUS_1, STATUS_2]
    assert parser.discarded_bytes == 3


@given(st.lists(st.tuples(noise, statuses), max_size=5), st.data())
def test_any_chunking_of_packets_and_noise(items: list, data: st.DataObject) -> None:
    """GIVEN packets with noise between them, cut at random points WHEN fed THEN the
    parser returns exactly those packets, in order."""
    stream = b"".join(garbage + encode(packet) for garbage, packet in items)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=8), label="cuts"))
    chunks = [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]
    parser = StatusParser()
    assert collect(parser, chunks) == [packet for _, packet in items]
    assert parser.buffered == 0


def test_a_damaged_packet_raises_once_and_the_next_one_survives() -> None:
    damaged = bytearray(REPLY_1)
    damaged[10] ^= 0x10
    parser = StatusParser()
    parser.feed(bytes(damaged) + REPLY_2)
    with pytest.raises(CrcError):
        parser.next_packet()
    assert list(parser) == [STATUS_2]
    assert parser.buffered == 0


@given(statuses, st.data())
def test_a_flipped_bit_never_yields_a_packet(packet: StatusPacket, data: st.DataObject) -> None:
    """Outside the length field, any single flipped bit is caught (header, id or CRC).

    A flipped length bit makes the parser wait for bytes that never come (the bus times
    out) or check the CRC at the wrong place, which any CRC-16 passes 1 time in 65536.
    """
    raw = encode(packet)
    byte = data.draw(st.integers(0, len(raw) - 1).filter(lambda i: i not in (5, 6)))
    damaged = bytearray(raw)
    damaged[byte] ^= 1 << data.draw(st.integers(0, 7))
    parser = StatusParser()
    parser.feed(bytes(damaged))
    received = []
    for _ in range(len(raw) + 1):
        try:
            next_packet = parser.next_packet()
        except CommunicationError:
            continue
        if next_packet is None:
            break
        received.append(next_packet)
    assert received == []


def test_a_false_header_with_a_huge_length_does_not_hold_back_real_packets() -> None:
    """Garbage that looks like a header claiming 1000 bytes is dropped as soon as a real
    header shows up inside the frame it claims."""
    false_header = bytes.fromhex("FF FF FD 00 05 E8 03 11 22")
    parser = StatusParser()
    parser.feed(false_header + REPLY_1)
    assert list(parser) == [STATUS_1]
    assert parser.discarded_bytes == len(false_header)


def test_impossible_ids_and_lengths_are_not_headers() -> None:
    parser = StatusParser(max_length=64)
    parser.feed(bytes.fromhex("FF FF FD 00 FF 04 00") + bytes.fromhex("FF FF FD 00 01 41 00"))
    parser.feed(bytes.fromhex("FF FF FD 00 01 02 00") + REPLY_2)
    assert list(parser) == [STATUS_2]


def test_a_trailing_partial_header_is_kept() -> None:
    parser = StatusParser()
    parser.feed(b"\x01\x02" + REPLY_1[:3])
    assert list(parser) == [] and parser.buffered == 3
    parser.feed(REPLY_1[3:])
    assert list(parser) == [STATUS_1]


def test_the_echo_of_our_instruction_is_skipped() -> None:
    parser = StatusParser()
    parser.feed(encode_instruction(1, Instruction.READ, bytes.fromhex("84 00 04 00")) + REPLY_1)
    assert list(parser) == [STATUS_1]
    assert parser.skipped_packets == 1


def test_instruction_parser_for_the_servo_side() -> None:
    ping = encode_instruction(1, Instruction.PING)
    write = encode_instruction(0xFE, Instruction.WRITE, bytes.fromhex("40 00 01"))
    parser = InstructionParser()
    parser.feed(ping[:5])
    assert parser.next_packet() is None
    parser.feed(ping[5:] + REPLY_2 + write)
    assert list(parser) == [
        InstructionPacket(1, Instruction.PING),
        InstructionPacket(0xFE, Instruction.WRITE, bytes.fromhex("40 00 01")),
    ]
    assert parser.skipped_packets == 1


def test_a_valid_frame_with_bad_contents_raises_and_is_dropped() -> None:
    """A status packet without its error byte passes the CRC but is not a status."""
    frame = bytearray(b"\xff\xff\xfd\x00\x01\x03\x00\x55")
    frame += crc16(frame).to_bytes(2, "little")
    parser = StatusParser()
    parser.feed(bytes(frame) + REPLY_1)
    with pytest.raises(CommunicationError, match="expected a status packet"):
        parser.next_packet()
    assert list(parser) == [STATUS_1]


def test_clear_drops_everything() -> None:
    parser = StatusParser()
    parser.feed(REPLY_1[:9])
    parser.clear()
    parser.feed(REPLY_2)
    assert list(parser) == [STATUS_2]
    assert parser.discarded_bytes == 9


def test_max_length_is_validated() -> None:
    with pytest.raises(ValueError, match="max_length"):
        StatusParser(max_length=2)

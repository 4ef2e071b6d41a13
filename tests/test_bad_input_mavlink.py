"""The companion's MAVLink link fed random bytes and damaged frames.

The Dynamixel parser has its own property tests (``test_dynamixel_stream.py``: any
chunking of packets and noise, any flipped bit); the link's were deterministic garbage
only (``test_link_mavlink.py``). Here the vehicle's side sends, after the link has found
it, datagrams of random bytes and of real frames with bytes changed, cut or spliced; the
link must count them, keep its reader alive and still deliver the next good frame.
"""

from __future__ import annotations

import asyncio
import socket
import time

from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as m

from companion.link import MavlinkLink, VehiclePose, px4_mode

WAIT_S = 5.0
"""Upper bound on any wait (a guard against hangs, not a measured time)."""


class Vehicle:
    """A pymavlink endpoint on 127.0.0.1 speaking as a PX4 autopilot (1, 1)."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.port = self.sock.getsockname()[1]
        self.addr: tuple[str, int] | None = None
        self.mav = m.MAVLink(self, 1, 1)

    def write(self, buf: bytes) -> None:
        assert self.addr is not None
        self.sock.sendto(bytes(buf), self.addr)

    def heartbeat(self) -> bytes:
        base = m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        custom = px4_mode("POSCTL").custom_mode
        return self.mav.heartbeat_encode(m.MAV_TYPE_HEXAROTOR, m.MAV_AUTOPILOT_PX4, base,
                                         custom, 4).pack(self.mav)  # fmt: skip

    def odometry(self, t_ms: int) -> bytes:
        msg = self.mav.odometry_encode(t_ms * 1000, 1, 1, 1.0, 2.0, -3.0, [1, 0, 0, 0], 0, 0, 0,
                                       0, 0, 0, [0] * 21, [0] * 21, 0, 0, 0)  # fmt: skip
        return msg.pack(self.mav)

    def attitude(self, t_ms: int) -> bytes:
        return self.mav.attitude_encode(t_ms, 0.1, -0.1, 0.5, 0, 0, 0).pack(self.mav)

    async def wait_for_link(self) -> None:
        """The first datagram from the link tells its address."""
        loop = asyncio.get_running_loop()
        async with asyncio.timeout(WAIT_S):
            _, self.addr = await loop.sock_recvfrom(self.sock, 65535)


@st.composite
def datagrams(draw) -> list[bytes]:
    """Random bytes, and real frames with a byte changed, cut short or spliced together."""
    vehicle = Vehicle()  # only its encoder; the socket closes at once
    vehicle.sock.close()
    frames = [vehicle.heartbeat(), vehicle.odometry(7), vehicle.attitude(7)]
    out = []
    for _ in range(draw(st.integers(1, 12))):
        kind = draw(st.sampled_from(["random", "changed", "cut", "spliced"]))
        frame = bytearray(draw(st.sampled_from(frames)))
        if kind == "random":
            out.append(draw(st.binary(min_size=1, max_size=300)))
        elif kind == "changed":
            for _ in range(draw(st.integers(1, 4))):
                frame[draw(st.integers(0, len(frame) - 1))] = draw(st.integers(0, 255))
            out.append(bytes(frame))
        elif kind == "cut":
            out.append(bytes(frame[: draw(st.integers(1, len(frame) - 1))]))
        else:
            other = draw(st.sampled_from(frames))
            out.append(bytes(frame[: draw(st.integers(1, len(frame)))] + other))
    return out


async def _deliver(chunks: list[bytes]) -> tuple[VehiclePose, object]:
    vehicle = Vehicle()
    link = MavlinkLink(f"udpout://127.0.0.1:{vehicle.port}", heartbeat_period_s=0.05)
    try:
        await link.open()
        await vehicle.wait_for_link()
        vehicle.write(vehicle.heartbeat())
        await link.wait_vehicle(WAIT_S)
        poses = link.subscribe(VehiclePose)
        for chunk in chunks:
            vehicle.write(chunk)
        # The good frame again until it arrives: a damaged header may claim the bytes after it.
        deadline = time.monotonic() + WAIT_S
        while True:
            assert time.monotonic() < deadline, "the good frame never arrived"
            vehicle.write(vehicle.odometry(123_456))
            try:
                async with asyncio.timeout(0.05):
                    while (pose := await poses.get()).time_boot_ms != 123_456:
                        pass
                break
            except TimeoutError:
                continue
        link.send_message(vehicle.mav.heartbeat_encode(18, 8, 0, 0, 4))  # sending still works
        return pose, link.stats
    finally:
        await link.close()
        vehicle.sock.close()


@settings(max_examples=20, deadline=None)
@given(datagrams())
def test_random_and_damaged_frames_never_stop_the_link(chunks: list[bytes]) -> None:
    pose, stats = asyncio.run(_deliver(chunks))
    assert pose.time_boot_ms == 123_456
    assert stats.messages_received >= 2  # the heartbeat and the good odometry at least
    assert min(stats.bad_frames, stats.garbage_bytes, stats.unknown_messages) >= 0

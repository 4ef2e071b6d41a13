"""The lockstep loop and the in-memory channels it serves (``sitl.vehicle.lockstep``,
``bytelink.memory``), with a counting simulation instead of the vehicle."""

from __future__ import annotations

import asyncio
import os

import pytest

from arm_driver.dynamixel.transport import open_transport as open_serial
from arm_driver.errors import CommunicationError
from bytelink.memory import attach, create_channel
from companion.link.errors import LinkClosedError
from companion.link.transport import open_transport
from companion.link.url import parse_link_url
from sitl.vehicle.lockstep import LockstepLoop, LockstepStall, run_lockstep


class Counter:
    """A simulation of 1 ms steps that, at the given step numbers, sends a chunk."""

    def __init__(self, channel=None, send_at=()) -> None:
        self.steps = 0
        self.served = 0
        self.channel = channel
        self.send_at = set(send_at)

    @property
    def time_s(self) -> float:
        return self.steps * 1e-3

    def step_until(self, until_s: float) -> None:
        self.steps += 1  # every step may send: one at a time
        if self.steps in self.send_at:
            self.channel.server.send(f"step {self.steps}".encode())

    def serve(self) -> None:
        self.served += 1


def test_sleeping_steps_the_simulation_to_the_deadline_and_no_further():
    sim = Counter()

    async def main() -> float:
        await asyncio.sleep(0.25)
        return asyncio.get_running_loop().time()

    woke_s = run_lockstep(sim, main())
    assert woke_s == pytest.approx(0.25) and sim.steps == 250


def test_a_reader_wakes_on_the_step_that_delivers_and_time_stops_while_it_works():
    with create_channel("test-lockstep-reader") as channel:
        sim = Counter(channel, send_at=(7, 40))
        got: list[tuple[int, bytes]] = []

        async def main() -> None:
            loop = asyncio.get_running_loop()
            end = attach("test-lockstep-reader")
            ready = asyncio.Event()
            loop.add_reader(end.fileno(), ready.set)
            while len(got) < 2:
                await ready.wait()
                ready.clear()
                data = end.receive()  # readiness is level-triggered, as epoll's: drain
                if data:
                    got.append((sim.steps, data))
                    end.send(b"reply")  # answered before the simulation moves on
                    assert channel.server.receive() == b"reply"
            loop.remove_reader(end.fileno())

        run_lockstep(sim, main())
    assert got == [(7, b"step 7"), (40, b"step 40")]


def test_a_wait_for_nothing_is_a_stall_not_a_hang():
    sim = Counter()

    async def main() -> None:
        await asyncio.Event().wait()

    loop = LockstepLoop(sim, max_idle_s=2.0)
    try:
        with pytest.raises(LockstepStall, match="waited 2 s"):
            loop.run_until_complete(main())
    finally:
        loop.close()
    assert sim.steps == 2001


def test_the_loop_watches_only_memory_channels():
    read, write = os.pipe()
    loop = LockstepLoop(Counter())
    try:
        with pytest.raises(ValueError, match="not an in-memory channel"):
            loop.add_reader(read, lambda: None)
    finally:
        loop.close()
        os.close(read)
        os.close(write)


def test_memory_channels_say_what_is_wrong():
    with create_channel("test-lockstep-names") as channel:
        with pytest.raises(ValueError, match="exists already"):
            create_channel("test-lockstep-names")
        with pytest.raises(LookupError, match="test-lockstep-names"):
            attach("nothing-here")
        channel.server.send(b"lost")  # nobody attached: dropped, as a datagram
        end = attach("test-lockstep-names")
        assert not end.readable
        with pytest.raises(LookupError, match="attached already"):
            attach("test-lockstep-names")
        channel.server.send(b"ab")
        channel.server.send(b"cd")
        assert end.receive_all() == b"abcd"
        end.close()
        with pytest.raises(ConnectionError, match="closed"):
            channel.server.send(b"x")


def test_memory_links_open_only_on_the_lockstep_loop():
    """A user who gives a memory URL to a real flight gets one clear error."""
    url = parse_link_url("memory://onboard")
    assert str(url) == "memory://onboard"

    async def open_link() -> None:
        open_transport(url, 1, 191)

    with pytest.raises(LinkClosedError, match="simulated time"):
        asyncio.run(open_link())

    async def open_bus() -> None:
        await open_serial("memory:servos", 1_000_000).open()

    with pytest.raises(CommunicationError, match="simulated time"):
        asyncio.run(open_bus())

"""The fan-out: independent subscriptions, bounded queues, the latest-value cache."""

import asyncio

import pytest

from companion.link import LinkClosedError
from companion.link.fanout import FanOut


def test_a_second_subscription_never_cancels_the_first():
    async def scenario():
        fan = FanOut()
        first = fan.subscribe(("A",), maxsize=8)
        second = fan.subscribe(("A", "B"), maxsize=8)
        for i in range(3):
            fan.publish("A", i)
        fan.publish("B", "b")
        got_first = [await first.get() for _ in range(3)]
        got_second = [await second.get() for _ in range(4)]
        second.close()
        fan.publish("A", 99)
        return got_first, got_second, await first.get(), second.pending(), fan.latest

    got_first, got_second, after, pending, latest = asyncio.run(scenario())
    assert got_first == [0, 1, 2]
    assert got_second == [0, 1, 2, "b"]
    assert after == 99
    assert pending == 0
    assert latest == {"A": 99, "B": "b"}


def test_full_queue_drops_oldest_and_counts():
    async def scenario():
        fan = FanOut()
        sub = fan.subscribe(("A",), maxsize=2)
        for i in range(5):
            fan.publish("A", i)
        return [await sub.get(), await sub.get()], sub.dropped

    items, dropped = asyncio.run(scenario())
    assert items == [3, 4]
    assert dropped == 3


def test_close_wakes_waiters_with_the_cause():
    async def scenario():
        fan = FanOut()
        sub = fan.subscribe(("A",), maxsize=2)
        waiter = asyncio.ensure_future(sub.get())
        await asyncio.sleep(0)
        cause = OSError("port gone")
        fan.close(cause)
        with pytest.raises(LinkClosedError) as info:
            await waiter
        assert info.value.__cause__ is cause
        with pytest.raises(LinkClosedError) as info:  # async for ends only on a normal close
            async for _ in sub:
                pass
        assert info.value.__cause__ is cause
        late = fan.subscribe(("A",), maxsize=1)
        with pytest.raises(LinkClosedError):
            await late.get()

    asyncio.run(scenario())


def test_async_for_ends_on_a_normal_close():
    async def scenario():
        fan = FanOut()
        sub = fan.subscribe(("A",), maxsize=4)
        fan.publish("A", 1)
        fan.close()
        return [item async for item in sub]

    assert asyncio.run(scenario()) == [1]


def test_bad_arguments():
    fan = FanOut()
    with pytest.raises(ValueError):
        fan.subscribe((), maxsize=1)
    with pytest.raises(ValueError):
        fan.subscribe(("A",), maxsize=0)

"""One reader, many consumers: a latest-value cache and bounded subscriber queues.

The reader calls :meth:`FanOut.publish` for every item; each item is stored as the
latest value of its key and put in the queue of every subscription that asked for the
key. Subscriptions are independent: a second subscription to a key never replaces or
cancels the first (the failure of MAVSDK-Python #60). A full queue drops its oldest
item and counts it in :attr:`Subscription.dropped`; the reader never waits for a slow
consumer. Keys are MAVLink message names (``"HEARTBEAT"``) or sample / event classes
(``VehiclePose``, ``LinkLost``).
"""

from __future__ import annotations

import asyncio
from collections.abc import Hashable
from typing import Generic, Self, TypeVar, cast

from companion.link.errors import LinkClosedError

__all__ = ["FanOut", "Key", "Subscription"]

Key = Hashable | type[object]
"""A key: a MAVLink message name or a sample / event class. (A class is hashable; the type
checker does not see ``type[X]`` as :class:`~collections.abc.Hashable`.)"""

_CLOSED = object()
_Item_co = TypeVar("_Item_co", covariant=True)


class Subscription(Generic[_Item_co]):
    """A queue of the items of some keys, from the moment it was made.

    Use ``await sub.get()`` or ``async for item in sub``; close it (or use it as a
    context manager) when done. After the link closes, ``get`` raises
    :class:`LinkClosedError` (with the reader's error as ``__cause__`` if it failed) and
    ``async for`` ends. The type parameter is the type of the items, as the link's
    ``subscribe`` knows it from the keys.
    """

    def __init__(self, fanout: FanOut, keys: frozenset[Key], maxsize: int) -> None:
        self._fanout = fanout
        self.keys = keys
        self._queue: asyncio.Queue[object] = asyncio.Queue(maxsize)
        self.dropped = 0
        """Items dropped because this queue was full."""

    def _put(self, item: object) -> None:
        if self._queue.full():
            self._queue.get_nowait()
            self.dropped += 1
        self._queue.put_nowait(item)

    def _close(self) -> None:
        if self._queue.full():
            self._queue.get_nowait()
            self.dropped += 1
        self._queue.put_nowait(_CLOSED)

    async def get(self) -> _Item_co:
        """The next item (waits for one)."""
        item = await self._queue.get()
        if item is _CLOSED:
            self._queue.put_nowait(_CLOSED)
            raise LinkClosedError("the link is closed") from self._fanout.error
        # The reader published it under one of ``keys``, whose item type the link's
        # subscribe stated when it made this subscription.
        return cast(_Item_co, item)

    def pending(self) -> int:
        """Items waiting in the queue."""
        return self._queue.qsize()

    def close(self) -> None:
        """Stop receiving (idempotent)."""
        self._fanout._remove(self)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __aiter__(self) -> Self:
        return self

    async def __anext__(self) -> _Item_co:
        try:
            return await self.get()
        except LinkClosedError:
            if self._fanout.error is not None:
                raise
            raise StopAsyncIteration from None


class FanOut:
    """Latest value per key and the subscriptions (used by the link's reader task)."""

    def __init__(self) -> None:
        self.latest: dict[Key, object] = {}
        self._subs: dict[Key, list[Subscription[object]]] = {}
        self.closed = False
        self.error: BaseException | None = None
        """Why the reader stopped, if it failed; None for a normal close."""

    def subscribe(self, keys: tuple[Key, ...], maxsize: int) -> Subscription[object]:
        if not keys:
            raise ValueError("subscribe to at least one key")
        if maxsize < 1:
            raise ValueError("maxsize must be at least 1")
        sub: Subscription[object] = Subscription(self, frozenset(keys), maxsize)
        if self.closed:
            sub._close()
            return sub
        for key in sub.keys:
            self._subs.setdefault(key, []).append(sub)
        return sub

    def _remove(self, sub: Subscription[object]) -> None:
        for key in sub.keys:
            subs = self._subs.get(key, [])
            if sub in subs:
                subs.remove(sub)

    def has_subscribers(self, key: Key) -> bool:
        """Whether some subscription takes the items of ``key``."""
        return bool(self._subs.get(key))

    def publish(self, key: Key, item: object) -> None:
        """Store ``item`` as the latest of ``key`` and queue it for its subscribers."""
        self.latest[key] = item
        for sub in self._subs.get(key, ()):
            sub._put(item)

    def close(self, error: BaseException | None = None) -> None:
        """Wake every subscriber with the end of the stream (idempotent)."""
        if self.closed:
            return
        self.closed = True
        self.error = error
        for sub in {s for subs in self._subs.values() for s in subs}:
            sub._close()
        self._subs.clear()

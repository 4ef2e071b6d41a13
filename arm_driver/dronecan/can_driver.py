"""The one place that works around pydronecan's python-can driver: a replacement driver.

Why: ``dronecan`` 1.0.27's own python-can driver (``dronecan.driver.python_can.PythonCAN``)
cannot be used with python-can >= 4.5:

- its writer thread calls ``bus.flush_tx_buffer()`` after every frame, which python-can
  >= 4.5 raises ``NotImplementedError`` for on most interfaces (socketcan, virtual), so
  no frame is ever confirmed and the error surfaces on the next send or receive
  (dronecan/pydronecan#79; python-can's side: hardbyte/python-can#1922);
- its ``receive(timeout)`` passes the timeout to ``bus.recv`` in milliseconds, a
  thousand times too long (dronecan/pydronecan#77), which would stall a control cycle;
- its constructor requires a ``bitrate`` keyword even for interfaces that have none.

The fix upstream (dronecan/pydronecan#78) is not in a release this project can pin.
So this module implements dronecan's driver interface
(:class:`dronecan.driver.common.AbstractDriver`: ``send_frame``, ``receive``, ``close``)
over a python-can bus the caller opened, and :class:`~arm_driver.dronecan.bus.DroneCanBus`
and the emulator (:mod:`sitl.servo.dronecan_node`) hand it to :class:`dronecan.node.Node`
instead of calling ``dronecan.make_node``. ``tests/test_dronecan_shim.py`` pins the
upstream bug (it fails once a dronecan release fixes it: then delete this module) and
shows frames crossing a virtual bus through this driver.

Threads: python-can's ``recv`` blocks, and some interfaces (virtual) have no file
descriptor an event loop could watch, so one daemon thread per driver receives frames
into a queue; :meth:`PythonCanDriver.receive` takes them from there (blocking with a
timeout in seconds, or not at all with 0), and ``on_frame`` is called from the thread
after each frame so an asyncio owner can wake up (``loop.call_soon_threadsafe``).
Sending is synchronous, straight to ``bus.send`` with a bounded timeout: no writer
thread, nothing to flush. A receive failure (interface down) is queued and raised by the
next :meth:`~PythonCanDriver.receive` as :class:`can.CanError`.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable

import can
from dronecan.driver.common import AbstractDriver, CANFrame

__all__ = ["PythonCanDriver"]

_POLL_S = 0.05
"""Longest the receiving thread blocks in ``bus.recv`` before checking for close [s]."""


class PythonCanDriver(AbstractDriver):
    """dronecan CAN driver over an open python-can bus (classic CAN, 29-bit ids).

    Parameters
    ----------
    bus
        An open python-can bus; the driver shuts it down on :meth:`close`.
    send_timeout_s
        Longest ``bus.send`` may block when the transmit queue is full [s].
    on_frame
        Called (from the receiving thread) after each received frame or receive error.
    """

    def __init__(
        self,
        bus: can.BusABC,
        *,
        send_timeout_s: float = 0.002,
        on_frame: Callable[[], None] | None = None,
    ) -> None:
        super().__init__()
        self._bus = bus
        self._send_timeout_s = send_timeout_s
        self._on_frame = on_frame
        self._frames: queue.SimpleQueue[CANFrame | Exception] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._receive_loop, name="can-rx", daemon=True)
        self._thread.start()

    def _receive_loop(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self._bus.recv(_POLL_S)
            except Exception as error:  # handed to the consumer by receive(), not lost
                self._frames.put(can.CanError(f"CAN receive failed: {error}"))
                if self._on_frame is not None:
                    self._on_frame()
                return
            if msg is None or msg.is_error_frame or msg.is_remote_frame:
                continue
            self._frames.put(CANFrame(msg.arbitration_id, bytearray(msg.data), msg.is_extended_id))
            if self._on_frame is not None:
                self._on_frame()

    def send_frame(self, frame: CANFrame) -> None:
        """Send one frame now (raises :class:`can.CanError` if the bus refuses it)."""
        if frame.canfd:
            raise can.CanError("CAN FD frames are not supported by this driver")
        msg = can.Message(
            arbitration_id=frame.id,
            is_extended_id=frame.extended,
            data=bytes(frame.data),
        )
        self._bus.send(msg, timeout=self._send_timeout_s)
        frame.ts_monotonic = time.monotonic()
        self._tx_hook(frame)

    def receive(self, timeout: float | None = None) -> CANFrame | None:
        """The next received frame, waiting up to ``timeout`` [s] (0: do not wait)."""
        try:
            if timeout == 0:
                item = self._frames.get_nowait()
            else:
                item = self._frames.get(timeout=timeout)
        except queue.Empty:
            return None
        if isinstance(item, Exception):
            raise item
        self._rx_hook(item)
        return item

    def close(self) -> None:
        """Stop the receiving thread and shut the bus down; safe to call twice."""
        if self._stop.is_set():
            return
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
        self._bus.shutdown()

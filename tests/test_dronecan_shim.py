"""arm_driver.dronecan.can_driver: why it exists, and that frames cross a bus through it.

``test_stock_driver_still_cannot_send`` pins the upstream bug the shim works around
(dronecan/pydronecan#79): when a dronecan release fixes it, that test fails, and the
shim module can be deleted in favour of ``dronecan.make_node``.
"""

from __future__ import annotations

import queue
import time
import uuid
from collections.abc import Iterator

import can
import dronecan
import pytest
from dronecan.driver.python_can import PythonCAN
from dronecan.node import Node

from arm_driver.dronecan.can_driver import PythonCanDriver

_ACTUATOR = dronecan.uavcan.equipment.actuator


@pytest.fixture
def channel() -> str:
    return f"shim-{uuid.uuid4().hex}"


@pytest.fixture
def pair(channel: str) -> Iterator[tuple[Node, Node]]:
    a = Node(PythonCanDriver(can.Bus(interface="virtual", channel=channel)), node_id=10)
    b = Node(PythonCanDriver(can.Bus(interface="virtual", channel=channel)), node_id=20)
    yield a, b
    a.close()
    b.close()


def _command(value: float) -> object:
    commands = [
        _ACTUATOR.Command(actuator_id=i, command_type=2, command_value=value) for i in (1, 2, 3)
    ]
    return _ACTUATOR.ArrayCommand(commands=commands)


@pytest.mark.filterwarnings("ignore:The 'bustype' argument:DeprecationWarning")
def test_stock_driver_still_cannot_send(channel: str) -> None:
    """dronecan 1.0.27 + python-can >= 4.5: the writer thread's flush_tx_buffer fails after
    the first frame sent, and every receive raises that failure from then on: a node that
    has sent can no longer hear the bus. Through the shim it can."""
    stock = PythonCAN(channel, bustype="virtual", bitrate=1_000_000)
    shim = PythonCanDriver(can.Bus(interface="virtual", channel=f"{channel}-shim"))
    peer = can.Bus(interface="virtual", channel=channel)
    shim_peer = can.Bus(interface="virtual", channel=f"{channel}-shim")
    try:
        stock.send(0x1234, b"\x01\x02", extended=True)
        reply = can.Message(arbitration_id=0x55, is_extended_id=True, data=b"\x07")
        peer.send(reply)
        deadline = time.monotonic() + 2.0
        error: Exception | None = None
        while error is None and time.monotonic() < deadline:
            try:
                stock.receive(0)  # not a timeout: dronecan passes it on in ms (#77)
            except Exception as raised:
                error = raised
            time.sleep(0.01)
        assert isinstance(error, NotImplementedError), (
            "dronecan's own python-can driver sends and receives fine now: the upstream bug "
            "(dronecan/pydronecan#79) is fixed, delete arm_driver/dronecan/can_driver.py"
        )
        shim.send(0x1234, b"\x01\x02", extended=True)
        assert shim_peer.recv(timeout=2.0) is not None
        shim_peer.send(reply)
        frame = shim.receive(2.0)
        assert frame is not None and (frame.id, bytes(frame.data)) == (0x55, b"\x07")
    finally:
        stock.close()
        shim.close()
        peer.shutdown()
        shim_peer.shutdown()


def test_a_multi_frame_transfer_crosses_the_virtual_bus(pair: tuple[Node, Node]) -> None:
    a, b = pair
    got: list[object] = []
    b.add_handler(_ACTUATOR.ArrayCommand, lambda event: got.append(event.message))
    a.broadcast(_command(0.25))  # 3 commands: 12 bytes, two frames with a transfer CRC
    deadline = time.monotonic() + 2.0
    while not got and time.monotonic() < deadline:
        b.spin(0.01)
    assert len(got) == 1
    assert [(c.actuator_id, c.command_type, c.command_value) for c in got[0].commands] == [
        (1, 2, 0.25),
        (2, 2, 0.25),
        (3, 2, 0.25),
    ]


def test_receive_with_zero_timeout_does_not_wait(pair: tuple[Node, Node]) -> None:
    a, _ = pair
    start = time.monotonic()
    assert a.can_driver.receive(0) is None
    assert a.spin(0) == 0
    # nothing to receive: the call returned without blocking for dronecan's 1 s default
    assert time.monotonic() - start < 0.5


def test_on_frame_is_called_per_received_frame(channel: str) -> None:
    calls: queue.SimpleQueue[int] = queue.SimpleQueue()
    driver = PythonCanDriver(
        can.Bus(interface="virtual", channel=channel), on_frame=lambda: calls.put(1)
    )
    sender = can.Bus(interface="virtual", channel=channel)
    try:
        sender.send(can.Message(arbitration_id=0x10, is_extended_id=True, data=b"\x00\xc0"))
        assert calls.get(timeout=2.0) == 1
        frame = driver.receive(1.0)
        assert frame is not None and frame.id == 0x10 and frame.extended
    finally:
        sender.shutdown()
        driver.close()
        driver.close()  # safe twice


def test_a_receive_failure_is_raised_to_the_consumer() -> None:
    class Broken(can.BusABC):
        def __init__(self) -> None:
            super().__init__(channel="broken")

        def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
            raise can.CanOperationError("interface went down")

        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            raise can.CanOperationError("interface went down")

    driver = PythonCanDriver(Broken())
    try:
        with pytest.raises(can.CanError, match="interface went down"):
            driver.receive(2.0)
        with pytest.raises(can.CanError):
            driver.send(0x10, b"\x00", extended=True)
    finally:
        driver.close()

"""Simulated DroneCAN actuator node on a python-can bus (the virtual bus in tests).

:class:`DroneCanActuatorNode` is a DroneCAN node (``dronecan`` package, node id 1-127)
hosting :class:`~sitl.servo.can_actuator.CanActuator` models. A background thread spins
the node::

    with DroneCanActuatorNode({1: CanActuator(1), 2: CanActuator(2)}, channel="arm") as sim:
        ...  # open dronecan://arm?interface=virtual with a client

What it answers (DSDL of ``uavcan``):

- ``equipment.actuator.ArrayCommand`` (1010): each command for a hosted actuator is
  applied (:meth:`CanActuator.command`), then a ``Status`` of each addressed actuator is
  published;
- ``equipment.actuator.Status`` (1011) is also published for every actuator each
  ``status_period_s``, commanded or not;
- ``equipment.safety.ArmingStatus`` (1100): arms or disarms every actuator;
- ``protocol.NodeStatus`` (341) every ``node_status_period_s`` and at once when the
  health changes: health OK, or ERROR while an actuator has hardware error bits, which
  go into ``vendor_specific_status_code`` (OR of the actuators' bits);
- ``protocol.RestartNode`` (5) with the DSDL's magic number: every actuator restarts
  (errors cleared, disarmed).

Time: before each command and each periodic Status, the actuators' loops advance by the
wall time elapsed, unless ``step_actuators`` is off because a SITL steps them with its
physics (under :attr:`DroneCanActuatorNode.lock`).

Faults (:class:`~sitl.servo.responder.Faults`, the same as the pty Dynamixel bus;
changeable while running with :meth:`DroneCanActuatorNode.set_faults`): ``silent_ids``
actuators whose Status is never published (they still take commands),
``crc_corruption_rate`` the probability that a published Status has its transfer CRC
corrupted (a Status takes two CAN frames, so it carries a transfer CRC that the receiver
checks), ``reply_delay_s`` a delay before each Status. Hardware errors are injected on
the actuator model (:meth:`CanActuator.inject_hardware_error`).

The CAN driver is :class:`arm_driver.dronecan.can_driver.PythonCanDriver`, for the reason
given there (dronecan/pydronecan#79).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from typing import Any

import can
import dronecan
import numpy as np
from dronecan.driver.common import CANFrame
from dronecan.node import Node

from arm_driver.dronecan.can_driver import PythonCanDriver
from arm_driver.errors import NodeHealth
from sitl.servo.can_actuator import CanActuator
from sitl.servo.responder import Faults

__all__ = ["NODE_NAME", "RESTART_MAGIC", "DroneCanActuatorNode"]

NODE_NAME = "org.sitl.servo.actuator"
"""Name the emulated node gives in ``protocol.GetNodeInfo`` (software version 1.0)."""

_ACTUATOR = dronecan.uavcan.equipment.actuator
_NODE_STATUS = dronecan.uavcan.protocol.NodeStatus
_MAX_STEP_S = 0.1
"""Largest wall-time gap the actuator loops are advanced by at once [s]."""
_SPIN_S = 0.05
"""Longest one spin of the node blocks before the thread checks for stop [s]."""
RESTART_MAGIC = 0xACCE551B1E
"""``uavcan.protocol.RestartNode.Request.MAGIC_NUMBER``."""


class _CorruptingDriver(PythonCanDriver):
    """Flips the first byte (the transfer CRC's low byte) of the next multi-frame transfer."""

    corrupt_next = False

    def send_frame(self, frame: CANFrame) -> None:
        tail = frame.data[-1]
        start, end = bool(tail & 0x80), bool(tail & 0x40)
        if self.corrupt_next and start and not end:
            frame.data[0] ^= 0xFF
            self.corrupt_next = False
        super().send_frame(frame)


class DroneCanActuatorNode:
    """Actuator models behind a DroneCAN node, served by a background thread.

    Parameters
    ----------
    actuators
        Actuator models by id (their ``actuator_id`` must match the key).
    channel
        python-can channel (a virtual bus channel name, or e.g. ``vcan0``).
    interface
        python-can interface.
    node_id
        The node's DroneCAN node id (1-127).
    faults
        Faults to inject from the start.
    status_period_s
        Period of the unsolicited Status of every actuator [s].
    node_status_period_s
        Period of NodeStatus [s] (DSDL: 0.002-1 s).
    step_actuators
        Advance the actuators' loops by wall time; off when a SITL steps them.
    """

    def __init__(
        self,
        actuators: Mapping[int, CanActuator],
        *,
        channel: str,
        interface: str = "virtual",
        node_id: int = 20,
        faults: Faults | None = None,
        status_period_s: float = 0.02,
        node_status_period_s: float = 0.5,
        step_actuators: bool = True,
    ) -> None:
        for actuator_id, actuator in actuators.items():
            if actuator.actuator_id != actuator_id:
                raise ValueError(f"actuator keyed {actuator_id} has id {actuator.actuator_id}")
        if not 1 <= node_id <= 127:
            raise ValueError(f"node id {node_id} out of range (1-127)")
        if not (status_period_s > 0.0 and 0.002 <= node_status_period_s <= 1.0):
            raise ValueError("status_period_s must be > 0, node_status_period_s in [0.002, 1]")
        self.actuators = dict(actuators)
        self.channel = channel
        self.interface = interface
        self.node_id = node_id
        self.lock = threading.Lock()
        """Held while the thread touches the actuators; hold it to touch them from outside."""
        self._faults = faults if faults is not None else Faults()
        self._rng = np.random.default_rng(self._faults.seed)
        self._status_period_s = status_period_s
        self._node_status_period_s = node_status_period_s
        self._step = step_actuators
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._node: Node | None = None
        self._driver: _CorruptingDriver | None = None
        self._last_step = 0.0
        self._health = NodeHealth.OK
        self.corrupted_replies = 0
        """Status transfers sent with a corrupted transfer CRC."""
        self.commands_received = 0
        """ArrayCommand messages received."""

    def set_faults(self, faults: Faults) -> None:
        """Replace the injected faults (re-seeds the corruption generator)."""
        with self.lock:
            self._faults = faults
            self._rng = np.random.default_rng(faults.seed)

    @property
    def url(self) -> str:
        """A ``dronecan://`` bus URL for clients (node id 10, interface and channel)."""
        return f"dronecan://{self.channel}?interface={self.interface}&node_id=10"

    # -- lifecycle ----------------------------------------------------------------------

    def start(self) -> None:
        """Open the CAN bus and start serving."""
        if self._thread is not None:
            raise RuntimeError("the simulated node is already started")
        bus = can.Bus(interface=self.interface, channel=self.channel)
        self._driver = _CorruptingDriver(bus)
        node = self._node = Node(
            self._driver,
            node_id=self.node_id,
            mode=_NODE_STATUS().MODE_OPERATIONAL,
            node_status_interval=self._node_status_period_s,
        )
        node.node_info.name = list(NODE_NAME.encode())
        node.node_info.software_version.major, node.node_info.software_version.minor = 1, 0
        node.add_handler(_ACTUATOR.ArrayCommand, self._on_command)
        node.add_handler(dronecan.uavcan.equipment.safety.ArmingStatus, self._on_arming)
        node.add_handler(dronecan.uavcan.protocol.RestartNode, self._on_restart)
        node.periodic(self._status_period_s, self._publish_all)
        self._last_step = time.monotonic()
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name="dronecan-node", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread and close the bus; safe to call twice."""
        if self._thread is None or self._node is None:
            return
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._node.close()
        self._thread = None
        self._node = None

    def __enter__(self) -> DroneCanActuatorNode:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    # -- the serving thread -----------------------------------------------------------

    def _serve(self) -> None:
        assert self._node is not None
        while not self._stop.is_set():
            try:
                self._node.spin(_SPIN_S)
            except dronecan.UAVCANException:
                continue  # a damaged incoming transfer: dropped, as a real node would

    def _advance(self) -> None:
        now = time.monotonic()
        if self._step:
            for actuator in self.actuators.values():
                actuator.step(min(now - self._last_step, _MAX_STEP_S))
        self._last_step = now

    def _on_command(self, event: Any) -> None:
        addressed = []
        with self.lock:
            self.commands_received += 1
            self._advance()
            for command in event.message.commands:
                actuator = self.actuators.get(int(command.actuator_id))
                if actuator is not None:
                    actuator.command(int(command.command_type), float(command.command_value))
                    addressed.append(actuator)
            self._publish(addressed)

    def _on_arming(self, event: Any) -> None:
        armed = int(event.message.status) == event.message.STATUS_FULLY_ARMED
        with self.lock:
            self._advance()
            for actuator in self.actuators.values():
                actuator.armed = armed

    def _on_restart(self, event: Any) -> Any:
        ok = int(event.request.magic_number) == RESTART_MAGIC
        if ok:
            with self.lock:
                for actuator in self.actuators.values():
                    actuator.restart()
                self._update_health()
        return dronecan.uavcan.protocol.RestartNode.Response(ok=ok)

    def _publish_all(self) -> None:
        with self.lock:
            self._advance()
            self._publish(list(self.actuators.values()))

    def _publish(self, actuators: list[CanActuator]) -> None:
        """Publish a Status of each actuator (the lock is held)."""
        assert self._node is not None and self._driver is not None
        faults = self._faults
        self._update_health()
        for actuator in actuators:
            if actuator.actuator_id in faults.silent_ids:
                continue
            if faults.reply_delay_s > 0.0:
                time.sleep(faults.reply_delay_s)
            position, force, speed, load = actuator.status()
            if faults.crc_corruption_rate and self._rng.random() < faults.crc_corruption_rate:
                self._driver.corrupt_next = True
                self.corrupted_replies += 1
            self._node.broadcast(
                _ACTUATOR.Status(
                    actuator_id=actuator.actuator_id,
                    position=position,
                    force=force,
                    speed=speed,
                    power_rating_pct=load,
                )
            )

    def _update_health(self) -> None:
        """NodeStatus health from the actuators' errors; published at once on a change."""
        assert self._node is not None
        bits = 0
        for actuator in self.actuators.values():
            bits |= int(actuator.hardware_error)
        health = NodeHealth.ERROR if bits else NodeHealth.OK
        self._node.health = int(health)
        self._node.vendor_specific_status_code = bits
        if health != self._health:
            self._health = health
            self._node.broadcast(
                _NODE_STATUS(
                    uptime_sec=int(time.monotonic() - self._node.start_time_monotonic),
                    health=int(health),
                    mode=_NODE_STATUS().MODE_OPERATIONAL,
                    vendor_specific_status_code=bits,
                )
            )

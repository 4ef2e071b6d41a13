"""The DroneCAN backend of :class:`~arm_driver.bus.ArmBus`: actuators on a CAN bus.

URL: ``dronecan://can0?interface=socketcan&node_id=10`` (``interface=virtual`` for
python-can's in-process virtual bus, the device then names its channel). Options:
``interface`` (python-can interface, default ``socketcan``), ``node_id`` (ours, 1-127,
default 10), ``bitrate`` [bit/s] (only for interfaces that set it), ``timeout_ms``,
``max_status_age_ms``, ``open_timeout_ms`` and ``arming`` (``0``/``1``). Each joint's
``servo_id`` is its DroneCAN *actuator id* (0-255), not a node id: one node may host
several actuators.

Messages (DSDL of the ``uavcan.equipment`` namespace, through the ``dronecan`` package):

- commands: ``actuator.ArrayCommand`` (1010), up to 15 ``actuator.Command`` per
  message, broadcast; COMMAND_TYPE_FORCE [N m] for joint torques, COMMAND_TYPE_POSITION
  [rad] for joint angles and the gripper;
- feedback: ``actuator.Status`` (1011), published by each actuator (position [rad],
  force [N m], speed [rad/s]); its fields are float16, so angles near pi resolve to
  about 2e-3 rad. The node that publishes an actuator's Status is the node whose
  ``protocol.NodeStatus`` (341) health the bus watches for that actuator;
- torque on/off: ``safety.ArmingStatus`` (1100), STATUS_FULLY_ARMED / STATUS_DISARMED,
  the message DroneCAN actuators use to enable their outputs. It is system-wide: keep
  the arm on a CAN bus of its own, or set ``arming=0`` (torque on/off then only sends
  zero-force commands). Turning torque off also commands zero force to every actuator.

Operating modes, honestly: DroneCAN has no persistent mode, each command carries its
type. CURRENT (torque) maps to COMMAND_TYPE_FORCE, the actuator closing its own current
loop and reporting its output torque as ``force``, so the joint's
``torque_constant_n_m_per_a`` and its friction keys (``viscous_friction_n_m_s_per_rad``,
``coulomb_friction_n_m``) are not used: the companion's config refuses friction on a
DroneCAN bus, and ``companion arm calibrate`` refuses the bus; POSITION maps to
COMMAND_TYPE_POSITION. CURRENT_BASED_POSITION (a position goal with a torque limit) has
no DroneCAN command and raises :class:`~arm_driver.bus.UnsupportedModeError`.

Feedback and deadlines: actuators publish Status on their own schedule (the emulator
after every command and periodically). A frame-receiving thread feeds a latest-value
cache (:mod:`arm_driver.dronecan.can_driver`); :meth:`read_joint_states` returns it at
once when every joint's Status is younger than ``max_status_age_s`` (default 50 ms), and
otherwise waits at most ``timeout_s`` (default 5 ms) for fresh ones, then raises
:class:`~arm_driver.errors.BusTimeoutError` naming the silent actuator. Each state's
timestamp is when *its* Status arrived. Opening waits up to ``open_timeout_s`` for a
Status of every joint and the gripper.

Damaged transfers (multi-frame transfer CRC, toggle or order errors) are dropped and
counted (:attr:`DroneCanBus.damaged_transfers`); a broadcast is not answered, so there
is nothing to retry: the next Status replaces a lost one, within the same deadline.
A node reporting health ERROR or CRITICAL raises
:class:`~arm_driver.errors.NodeHealthError` for its joints. A CAN send or receive
failure raises :class:`~arm_driver.errors.CommunicationError`.

Safe state (see :mod:`arm_driver.bus`): joints in current or unknown mode get a
zero-force ArrayCommand, then ArmingStatus DISARMED (with ``arming``); position-mode
joints and the gripper are left tracking their goals.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import can
import dronecan
from dronecan.node import Node
from dronecan.transport import TransferError

from arm_driver.bus import (
    ArmBus,
    DeviceInfo,
    GripperConfig,
    JointConfig,
    JointState,
    OperatingMode,
)
from arm_driver.dronecan.can_driver import PythonCanDriver
from arm_driver.errors import (
    ArmDriverError,
    BusTimeoutError,
    CommunicationError,
    NodeHealth,
    NodeHealthError,
)
from arm_driver.url import convert_options, flag, milliseconds

__all__ = ["MAX_COMMANDS_PER_MESSAGE", "DroneCanBus"]

_ACTUATOR = dronecan.uavcan.equipment.actuator
_NODE_STATUS = dronecan.uavcan.protocol.NodeStatus
_ARMING = dronecan.uavcan.equipment.safety.ArmingStatus
MAX_COMMANDS_PER_MESSAGE = 15
"""``actuator.ArrayCommand`` carries at most 15 commands (DSDL ``Command[<=15]``)."""
_SCAN_LISTEN_S = 1.1
_SCAN_INFO_TIMEOUT_S = 0.5
FORCE = _ACTUATOR.Command().COMMAND_TYPE_FORCE
POSITION = _ACTUATOR.Command().COMMAND_TYPE_POSITION


@dataclass(frozen=True)
class _Status:
    """The latest ``actuator.Status`` of one actuator."""

    position_rad: float
    force_n_m: float
    speed_rad_s: float
    node_id: int
    stamp_s: float
    """``time.monotonic()`` when its first frame arrived [s]."""


class DroneCanBus(ArmBus):
    """DroneCAN actuators over python-can, in joint space.

    Parameters
    ----------
    device
        CAN channel, e.g. ``can0`` (socketcan) or any name (virtual).
    joints
        The arm's joints; ``servo_id`` is the actuator id (0-255).
    gripper
        The gripper's actuator, driven with position commands.
    interface
        python-can interface name (``socketcan``, ``virtual``, ...).
    node_id
        Our DroneCAN node id (1-127), the source of our broadcasts.
    bitrate
        Bit rate for interfaces whose driver sets it [bit/s]; None leaves it.
    timeout_s
        Longest a read waits for fresh Status messages [s].
    max_status_age_s
        Oldest Status a read returns without waiting [s].
    open_timeout_s
        Longest opening waits for a first Status of every actuator [s].
    arming
        Send ``safety.ArmingStatus`` on torque on/off.
    max_consecutive_failures
        Link failures in a row that mark the bus failed.
    """

    supported_modes = frozenset({OperatingMode.CURRENT, OperatingMode.POSITION})

    def __init__(
        self,
        device: str,
        joints: Sequence[JointConfig],
        *,
        gripper: GripperConfig | None = None,
        interface: str = "socketcan",
        node_id: int = 10,
        bitrate: int | None = None,
        timeout_s: float = 0.005,
        max_status_age_s: float = 0.05,
        open_timeout_s: float = 0.5,
        arming: bool = True,
        max_consecutive_failures: int = 3,
    ) -> None:
        super().__init__(joints, gripper=gripper, max_consecutive_failures=max_consecutive_failures)
        self._ids = [joint.servo_id for joint in self.joints] + (
            [gripper.servo_id] if gripper else []
        )
        for actuator_id in self._ids:
            if not 0 <= actuator_id <= 255:
                raise ValueError(f"DroneCAN actuator id {actuator_id} out of range (0-255)")
        if not 1 <= node_id <= 127:
            raise ValueError(f"DroneCAN node id {node_id} out of range (1-127)")
        for name, value in (
            ("timeout_s", timeout_s),
            ("max_status_age_s", max_status_age_s),
            ("open_timeout_s", open_timeout_s),
        ):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} {value} must be positive and finite")
        self._device = device
        self._interface = interface
        self._node_id = node_id
        self._bitrate = bitrate
        self._timeout_s = timeout_s
        self._max_age_s = max_status_age_s
        self._open_timeout_s = open_timeout_s
        self._arming = arming
        self._node: Node | None = None
        self._wake: asyncio.Event | None = None
        self._status: dict[int, _Status] = {}
        self._health: dict[int, tuple[NodeHealth, int]] = {}
        self.damaged_transfers = 0
        """Received transfers dropped as damaged (CRC, toggle, order) since the bus opened."""

    @classmethod
    def options_from_url(cls, options: Mapping[str, str]) -> dict[str, Any]:
        """``interface``, ``node_id``, ``bitrate``, ``timeout_ms``, ``max_status_age_ms``,
        ``open_timeout_ms``, ``arming`` -> keywords."""
        convert: dict[str, tuple[str, Any]] = {
            "interface": ("interface", str),
            "node_id": ("node_id", int),
            "bitrate": ("bitrate", int),
            "timeout_ms": ("timeout_s", milliseconds),
            "max_status_age_ms": ("max_status_age_s", milliseconds),
            "open_timeout_ms": ("open_timeout_s", milliseconds),
            "arming": ("arming", flag),
        }
        return convert_options("dronecan", options, convert)

    # -- the node -------------------------------------------------------------------------

    def _on_status(self, event: Any) -> None:
        msg = event.message
        self._status[int(msg.actuator_id)] = _Status(
            position_rad=float(msg.position),
            force_n_m=float(msg.force),
            speed_rad_s=float(msg.speed),
            node_id=int(event.transfer.source_node_id),
            stamp_s=float(event.transfer.ts_monotonic),
        )

    def _on_node_status(self, event: Any) -> None:
        msg = event.message
        health = NodeHealth(int(msg.health))
        self._health[int(event.transfer.source_node_id)] = (
            health,
            int(msg.vendor_specific_status_code),
        )

    def _pump(self) -> None:
        """Handle every frame received so far (non-blocking)."""
        assert self._node is not None
        while True:
            try:
                self._node.spin(0)
                return
            except TransferError:
                self.damaged_transfers += 1
            except (can.CanError, OSError) as error:
                raise CommunicationError(f"CAN bus {self._device!r}: {error}") from error

    def _broadcast(self, message: Any) -> None:
        assert self._node is not None
        try:
            self._node.broadcast(message)
        except (can.CanError, OSError) as error:
            raise CommunicationError(f"CAN bus {self._device!r}: send failed: {error}") from error

    def _command(self, commands: Mapping[int, tuple[int, float]]) -> None:
        """Broadcast ``actuator id -> (command type, value)`` in ArrayCommands of <= 15."""
        items = [
            _ACTUATOR.Command(actuator_id=i, command_type=kind, command_value=value)
            for i, (kind, value) in commands.items()
        ]
        for start in range(0, len(items), MAX_COMMANDS_PER_MESSAGE):
            chunk = items[start : start + MAX_COMMANDS_PER_MESSAGE]
            self._broadcast(_ACTUATOR.ArrayCommand(commands=chunk))

    async def _wait_for_status(self, ids: Sequence[int], since_s: float, timeout_s: float) -> None:
        """Wait until every actuator in ``ids`` has a Status stamped at or after ``since_s``."""
        assert self._wake is not None
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while True:
            self._wake.clear()
            self._pump()
            missing = [i for i in ids if i not in self._status or self._status[i].stamp_s < since_s]
            if not missing:
                return
            if loop.time() >= deadline:
                error = BusTimeoutError(
                    missing[0], timeout_s, what="uavcan.equipment.actuator.Status"
                )
                if len(missing) > 1:
                    error.add_note(f"actuators {missing} sent no fresh Status")
                raise error
            try:
                async with asyncio.timeout_at(deadline):
                    await self._wake.wait()
            except TimeoutError:
                pass

    def _check_health(self, ids: Sequence[int]) -> None:
        for actuator_id in ids:
            status = self._status.get(actuator_id)
            if status is None or status.node_id not in self._health:
                continue
            health, code = self._health[status.node_id]
            if health >= NodeHealth.ERROR:
                raise NodeHealthError(actuator_id, status.node_id, health, code)

    # -- hooks ------------------------------------------------------------------------------

    def _start_node(self) -> None:
        """Open the CAN bus, start receiving and make our node (nothing is awaited)."""
        self._status.clear()
        self._health.clear()
        self.damaged_transfers = 0
        loop = asyncio.get_running_loop()
        wake = self._wake = asyncio.Event()

        def woken() -> None:
            try:
                loop.call_soon_threadsafe(wake.set)
            except RuntimeError:  # the loop closed before the driver: nothing to wake
                pass

        try:
            if self._bitrate is None:  # the interface's own default (or none, on virtual)
                bus = can.Bus(interface=self._interface, channel=self._device)
            else:
                bus = can.Bus(
                    interface=self._interface, channel=self._device, bitrate=self._bitrate
                )
        except (can.CanError, OSError, ValueError, ImportError) as error:
            raise CommunicationError(
                f"cannot open CAN channel {self._device!r} with interface "
                f"{self._interface!r}: {error}"
            ) from error
        driver = PythonCanDriver(bus, on_frame=woken)
        self._node = Node(
            driver,
            node_id=self._node_id,
            mode=_NODE_STATUS().MODE_OPERATIONAL,
            catch_handler_exceptions=False,
        )
        self._node.add_handler(_ACTUATOR.Status, self._on_status)
        self._node.add_handler(_NODE_STATUS, self._on_node_status)

    async def _open_hook(self) -> tuple[OperatingMode | None, bool | None]:
        self._start_node()
        await self._wait_for_status(self._ids, -math.inf, self._open_timeout_s)
        self._check_health(self._ids)
        return None, None

    @classmethod
    async def scan(cls, device: str, ids: Sequence[int], **options: Any) -> list[DeviceInfo]:
        """Listen for ``listen_s`` (1.1 s: NodeStatus comes at least every second) for the
        actuators in ``ids`` publishing Status, then ask each hosting node for its
        ``protocol.GetNodeInfo`` (name, software version)."""
        probe = cls(device, [JointConfig("probe", 0, 1.0, 0.0)], **options)
        probe._start_node()
        node = probe._node
        assert node is not None
        infos: dict[int, Any] = {}
        try:
            loop = asyncio.get_running_loop()
            end = loop.time() + _SCAN_LISTEN_S
            while loop.time() < end:
                probe._pump()
                await asyncio.sleep(0.01)
            nodes = {s.node_id for i, s in probe._status.items() if i in ids}
            for node_id in sorted(nodes):
                node.request(
                    dronecan.uavcan.protocol.GetNodeInfo.Request(),
                    node_id,
                    lambda event, n=node_id: infos.__setitem__(n, event),
                    timeout=_SCAN_INFO_TIMEOUT_S,
                )
            end = loop.time() + _SCAN_INFO_TIMEOUT_S
            while loop.time() < end and len(infos) < len(nodes):
                probe._pump()
                await asyncio.sleep(0.01)
        finally:
            await probe._close_hook()
        found = []
        for actuator_id in sorted(i for i in probe._status if i in ids):
            node_id = probe._status[actuator_id].node_id
            event = infos.get(node_id)
            if event is None:
                name, version = "no GetNodeInfo answer", "?"
            else:
                name = bytes(event.response.name).decode("ascii", "replace")
                sw = event.response.software_version
                version = f"{sw.major}.{sw.minor}"
            found.append(DeviceInfo(actuator_id, f"DroneCAN node {node_id} {name!r}", version))
        return found

    async def _close_hook(self) -> None:
        if self._node is not None:
            self._node.close()
            self._node = None

    async def _set_torque_hook(self, enabled: bool) -> None:
        self._pump()
        if not enabled:
            self._command(dict.fromkeys(self._ids, (FORCE, 0.0)))
        if self._arming:
            status = _ARMING().STATUS_FULLY_ARMED if enabled else _ARMING().STATUS_DISARMED
            self._broadcast(_ARMING(status=status))
        if enabled:
            self._check_health(self._ids)

    async def _set_mode_hook(self, mode: OperatingMode) -> None:
        self._pump()  # nothing to send: each command carries its type

    async def _write_torques_hook(self, torques_n_m: Mapping[JointConfig, float]) -> None:
        self._command(
            {joint.servo_id: (FORCE, joint.direction * t) for joint, t in torques_n_m.items()}
        )
        self._pump()
        self._check_health([joint.servo_id for joint in torques_n_m])

    async def _write_positions_hook(self, positions_rad: Mapping[JointConfig, float]) -> None:
        self._command(
            {
                joint.servo_id: (POSITION, joint.servo_angle_rad(angle))
                for joint, angle in positions_rad.items()
            }
        )
        self._pump()
        self._check_health([joint.servo_id for joint in positions_rad])

    async def _read_states_hook(self) -> dict[str, JointState]:
        ids = [joint.servo_id for joint in self.joints]
        await self._wait_for_status(ids, time.monotonic() - self._max_age_s, self._timeout_s)
        self._check_health(ids)
        states = {}
        for joint in self.joints:
            status = self._status[joint.servo_id]
            values = (status.position_rad, status.speed_rad_s, status.force_n_m)
            if not all(math.isfinite(v) for v in values):
                raise ArmDriverError(
                    f"actuator {joint.servo_id} reports unknown (NaN) position, speed or "
                    "force; this backend needs all three",
                    servo_id=joint.servo_id,
                )
            states[joint.name] = JointState(
                name=joint.name,
                position_rad=joint.joint_angle_rad(status.position_rad),
                velocity_rad_s=joint.direction * status.speed_rad_s,
                torque_n_m=joint.direction * status.force_n_m,
                timestamp_s=status.stamp_s,
            )
        return states

    async def _write_gripper_hook(self, servo_angle_rad: float) -> None:
        gripper = self.gripper
        assert gripper is not None
        self._command({gripper.servo_id: (POSITION, servo_angle_rad)})
        self._pump()
        self._check_health([gripper.servo_id])

    async def _safe_state_hook(self) -> None:
        if self.operating_mode not in (OperatingMode.CURRENT, None) or self._node is None:
            return
        self._command({joint.servo_id: (FORCE, 0.0) for joint in self.joints})
        if self._arming:
            self._broadcast(_ARMING(status=_ARMING().STATUS_DISARMED))

"""The arm's servo bus: one asynchronous, joint-space API in SI units, several backends.

Modelled on python-can's ``BusABC``: the public methods of :class:`ArmBus` hold the
shared policy (bus state, one transaction at a time, unknown joints, limits checked
before anything is sent, operating-mode checks, counting link failures and the safe
state); a backend overrides small ``_..._hook`` methods that only talk to its hardware.
The lifecycle lives in the base class and never relies on a subclass calling ``super()``.

Backends are registered by name (the URL scheme) as ``"module:Class"`` strings and
imported only when chosen, so a missing optional dependency of one backend never breaks
another::

    async with open_bus("dynamixel:///dev/ttyUSB0?baud=1000000", joints) as bus:
        await bus.set_operating_mode(OperatingMode.CURRENT)
        await bus.enable_torque()
        states = await bus.read_joint_states()
        await bus.write_joint_torques({"shoulder": 0.4, "elbow": -0.1})

Conventions: angles [rad], rates [rad/s], torques [N m], all in the *joint* frame,
counter-clockwise positive about the joint axis as the arm's model defines it; a joint's
``direction`` and ``zero_offset_rad`` map it to the servo shaft (see :class:`JointConfig`).
Timestamps are ``time.monotonic()`` [s] when the reply was received.

Failure and safe state: a transaction that times out or returns garbage (after the
backend's bounded retries) counts as a link failure; ``max_consecutive_failures`` in a
row mark the bus FAILED. A failed bus raises :class:`BusFailedError` for every command
until it is closed and opened again, and the backend makes a best-effort attempt at the
safe state, which :meth:`ArmBus.close` also applies:

- joints in current (torque) mode, or in an unknown mode, get zero torque and then torque
  off: they go limp. A torque command is only right for the state it was computed for;
  held after the controller lost the bus it can drive the arm into its stops or into the
  vehicle at full current. A limp two-joint arm under a multirotor settles hanging down,
  a bounded disturbance the attitude controller rejects;
- joints in a position mode and the gripper are left as they are: each servo keeps
  tracking its last goal position with its own current limit, a bounded and stable
  behaviour, and a gripper that went limp would drop its payload in flight.

The safe state needs a live host. For a host that crashes or hangs, a backend may arm
a timeout in the servos themselves that stops current-mode joints when commands stop
(the Dynamixel backend's ``watchdog_ms``, the servos' Bus Watchdog).

Only a broken link counts as a failure: a servo that answers with an error
(:class:`~arm_driver.errors.InstructionError`, :class:`~arm_driver.errors.HardwareError`)
proves the link works and is reported to the caller, not acted on.
"""

from __future__ import annotations

import abc
import asyncio
import enum
import importlib
import logging
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, ParamSpec, Protocol, TypeVar, cast

from arm_driver.errors import ArmDriverError, BusTimeoutError, CommunicationError, LimitError
from arm_driver.joint import GripperConfig, GripperState, JointConfig, JointState
from arm_driver.url import parse_bus_url

__all__ = [
    "ArmBus",
    "BackendUnavailableError",
    "BusFailedError",
    "BusState",
    "BusStateError",
    "DeviceInfo",
    "GripperConfig",
    "GripperState",
    "JointConfig",
    "JointState",
    "OperatingMode",
    "UnsupportedModeError",
    "available_backends",
    "backend_class",
    "open_bus",
    "open_buses",
    "register_backend",
    "scan_bus",
]

_LOG = logging.getLogger(__name__)

_P = ParamSpec("_P")
_T = TypeVar("_T")


class OperatingMode(enum.Enum):
    """How the servos are driven."""

    CURRENT = "current"
    """Torque control: goal current from a joint torque."""
    POSITION = "position"
    """Position control with the servo's own loop and current limit."""
    CURRENT_BASED_POSITION = "current_based_position"
    """Position control whose current is limited by the joint's torque limit."""


class BusState(enum.Enum):
    """Lifecycle of a bus."""

    CLOSED = "closed"
    OPEN = "open"
    FAILED = "failed"


class BusStateError(ArmDriverError, RuntimeError):
    """The bus cannot do this now (closed, wrong operating mode, torque on, no gripper)."""


class BusFailedError(BusStateError):
    """The bus failed (repeated link failures); close it and open it again."""


class UnsupportedModeError(ArmDriverError, ValueError):
    """The backend's protocol cannot drive the joints in this operating mode."""


class BackendUnavailableError(ArmDriverError, LookupError):
    """No backend of that name, or one that is planned but not implemented."""


@dataclass(frozen=True)
class DeviceInfo:
    """A servo found by :func:`scan_bus`.

    Attributes
    ----------
    servo_id
        Its id on the bus (Dynamixel id, DroneCAN actuator id).
    model
        What it says it is (Dynamixel model number, DroneCAN node id and name).
    firmware
        Its firmware or software version, as the device reports it.
    """

    servo_id: int
    model: str
    firmware: str


_OPEN_BUSES: set[ArmBus] = set()


def open_buses() -> tuple[ArmBus, ...]:
    """Buses opened and not closed yet (a test fixture fails tests that leak one)."""
    return tuple(_OPEN_BUSES)


class ArmBus(abc.ABC):
    """An arm's servo bus in joint space; open with ``async with`` or :meth:`open`.

    Parameters
    ----------
    joints
        The arm's joints, in the order states are returned.
    gripper
        The gripper's servo, if any.
    max_consecutive_failures
        Link failures in a row that mark the bus FAILED.
    """

    supported_modes: frozenset[OperatingMode] = frozenset(OperatingMode)
    """Operating modes the backend's protocol can drive; others raise
    :class:`UnsupportedModeError` before anything is sent."""

    def __init__(
        self,
        joints: Sequence[JointConfig],
        *,
        gripper: GripperConfig | None = None,
        max_consecutive_failures: int = 3,
    ) -> None:
        joints = tuple(joints)
        if not joints:
            raise ValueError("an arm bus needs at least one joint")
        names = [joint.name for joint in joints]
        if len(set(names)) != len(names):
            raise ValueError(f"duplicate joint names in {names}")
        ids = [joint.servo_id for joint in joints] + ([gripper.servo_id] if gripper else [])
        if len(set(ids)) != len(ids):
            raise ValueError(f"duplicate servo ids in {ids}")
        if max_consecutive_failures < 1:
            raise ValueError("max_consecutive_failures must be >= 1")
        self._joints = {joint.name: joint for joint in joints}
        self._gripper = gripper
        self._torque_max = {joint.name: joint.torque_max_n_m for joint in joints}
        self._max_failures = max_consecutive_failures
        self._failures = 0
        self._state = BusState.CLOSED
        self._mode: OperatingMode | None = None
        self._torque: bool | None = None
        self._lock = asyncio.Lock()
        self.retried_replies = 0
        """Damaged replies (CRC, framing) the backend asked for again; 0 for a backend that
        does not retry."""

    # -- properties ---------------------------------------------------------------------

    @property
    def joints(self) -> tuple[JointConfig, ...]:
        """The joints, in configuration order."""
        return tuple(self._joints.values())

    @property
    def gripper(self) -> GripperConfig | None:
        """The gripper's configuration, if any."""
        return self._gripper

    @property
    def state(self) -> BusState:
        """CLOSED, OPEN or FAILED."""
        return self._state

    @property
    def operating_mode(self) -> OperatingMode | None:
        """The joints' operating mode, None if unknown or mixed."""
        return self._mode

    @property
    def torque_enabled(self) -> bool | None:
        """Torque is on for every servo (True), off for all (False), or unknown (None)."""
        return self._torque

    def torque_limit_n_m(self, joint: str) -> float:
        """Largest torque magnitude a command to ``joint`` may ask for [N m]."""
        return self._torque_max[joint]

    def set_torque_constants(self, values_n_m_per_a: Mapping[str, float]) -> None:
        """Read and command the named joints through these torque constants [N m/A] from
        now on (measured ones: ``companion.mission.servo_check``). Raises ValueError for an
        unknown joint or a constant that is not positive and finite; nothing is changed
        then."""
        unknown = sorted(set(values_n_m_per_a) - set(self._joints))
        if unknown:
            raise ValueError(f"unknown joint(s) {unknown}; joints are {list(self._joints)}")
        joints = {
            name: replace(self._joints[name], torque_constant_n_m_per_a=float(kt))
            for name, kt in values_n_m_per_a.items()
        }
        self._joints.update(joints)

    @property
    def watchdog_s(self) -> float:
        """Silence [s] after which the servos stop current-mode joints by themselves (0:
        no such timeout); :meth:`enable_torque` re-arms them after a trip."""
        return 0.0

    # -- lifecycle ----------------------------------------------------------------------

    async def open(self) -> None:
        """Open the link and check the servos; a no-op if already open.

        Raises
        ------
        BusFailedError
            The bus failed and was not closed since.
        ArmDriverError
            The link cannot be opened or a servo is missing or wrong; nothing stays open.
        """
        if self._state is BusState.OPEN:
            return
        if self._state is BusState.FAILED:
            raise BusFailedError("the bus failed; close it before opening it again")
        try:
            self._mode, self._torque = await self._open_hook()
        except BaseException:
            await self._close_hook()
            raise
        self._failures = 0
        self._state = BusState.OPEN
        _OPEN_BUSES.add(self)

    async def close(self) -> None:
        """Apply the safe state (best effort) and close the link; safe to call twice."""
        if self._state is BusState.CLOSED:
            return
        self._state = BusState.CLOSED
        _OPEN_BUSES.discard(self)
        try:
            async with self._lock:
                await self._safe_state_logged()
        finally:
            await self._close_hook()

    async def __aenter__(self) -> ArmBus:
        await self.open()
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    async def _safe_state_logged(self) -> None:
        try:
            await self._safe_state_hook()
        except ArmDriverError as error:
            _LOG.warning("could not apply the safe state: %s", error)

    # -- commands -----------------------------------------------------------------------

    async def enter_safe_state(self) -> None:
        """Mark the bus FAILED and apply the safe state now (best effort): for a caller
        whose own criterion says the link cannot be trusted before
        ``max_consecutive_failures`` (a flight app's time limit). Commands then raise
        :class:`BusFailedError` until the bus is closed and opened again."""
        self._check_open()
        async with self._lock:
            self._state = BusState.FAILED
            await self._safe_state_logged()

    async def enable_torque(self) -> None:
        """Turn torque on for every joint servo and the gripper."""
        await self._transact(self._set_torque_hook, True)
        self._torque = True

    async def disable_torque(self) -> None:
        """Turn torque off for every joint servo and the gripper: the arm goes limp."""
        await self._transact(self._set_torque_hook, False)
        self._torque = False

    async def set_operating_mode(self, mode: OperatingMode) -> None:
        """Set the joints' operating mode; torque must be off (the mode is in EEPROM).

        Raises
        ------
        UnsupportedModeError
            The backend cannot drive this mode (see :attr:`supported_modes`).
        BusStateError
            Torque is on or unknown: the driver does not turn it off for you, as the arm
            would go limp.
        """
        mode = OperatingMode(mode)
        if mode not in self.supported_modes:
            have = ", ".join(sorted(m.value for m in self.supported_modes))
            raise UnsupportedModeError(
                f"{type(self).__name__} cannot drive {mode.value} mode; it supports {have}"
            )
        if self._torque is not False:
            raise BusStateError(
                f"cannot set {mode.value} mode with torque on or unknown; "
                "call disable_torque() first (the arm goes limp)"
            )
        self._mode = None
        await self._transact(self._set_mode_hook, mode)
        self._mode = mode

    async def write_joint_torques(self, torques_n_m: Mapping[str, float]) -> None:
        """Command joint torques [N m] (current mode); every limit is checked first.

        Raises
        ------
        LimitError
            A torque above the joint's limit (or not finite); nothing was sent.
        BusStateError
            The bus is not in current mode.
        """
        self._require_mode(OperatingMode.CURRENT)
        commands = self._joint_commands(torques_n_m)
        for joint, torque in commands.items():
            limit = self._torque_max[joint.name]
            if not abs(torque) <= limit:
                raise LimitError(
                    joint.name, torque, -limit, limit, unit="N m", servo_id=joint.servo_id
                )
        await self._transact(self._write_torques_hook, commands)

    async def write_joint_positions(self, positions_rad: Mapping[str, float]) -> None:
        """Command joint angles [rad] (a position mode); every limit is checked first.

        Raises
        ------
        LimitError
            An angle outside the joint's limits (or not finite); nothing was sent.
        BusStateError
            The bus is not in a position mode.
        """
        self._require_mode(OperatingMode.POSITION, OperatingMode.CURRENT_BASED_POSITION)
        commands = self._joint_commands(positions_rad)
        for joint, angle in commands.items():
            lower, upper = joint.position_min_rad, joint.position_max_rad
            if not lower <= angle <= upper:
                raise LimitError(
                    joint.name, angle, lower, upper, unit="rad", servo_id=joint.servo_id
                )
        await self._transact(self._write_positions_hook, commands)

    async def hold_in_place(self) -> dict[str, JointState]:
        """Make the joints hold where they are on the servos' own position loop: torque off,
        a position mode (current-based where the backend has it, the current limited by
        each joint's torque limit), goal = the present angles within the joints' limits,
        torque on. The arm is limp for the few transactions this takes. Returns the joint
        states read for the goal. A position-mode joint is left holding by :meth:`close`."""
        await self.disable_torque()
        based = OperatingMode.CURRENT_BASED_POSITION
        await self.set_operating_mode(
            based if based in self.supported_modes else OperatingMode.POSITION
        )
        states = await self.read_joint_states()
        await self.write_joint_positions(
            {
                joint.name: min(
                    max(states[joint.name].position_rad, joint.position_min_rad),
                    joint.position_max_rad,
                )
                for joint in self.joints
            }
        )
        await self.enable_torque()
        return states

    async def read_joint_states(self) -> dict[str, JointState]:
        """Every joint's position, velocity and torque, read in one transaction."""
        return await self._transact(self._read_states_hook)

    async def open_gripper(self) -> None:
        """Move the gripper to its open position."""
        gripper = self._require_gripper()
        await self._transact(self._write_gripper_hook, gripper.open_position_rad)

    async def close_gripper(self) -> None:
        """Move the gripper to its closed position."""
        gripper = self._require_gripper()
        await self._transact(self._write_gripper_hook, gripper.closed_position_rad)

    async def read_gripper(self) -> GripperState:
        """The gripper servo's position and current (:class:`BusStateError` from a backend
        that cannot read them)."""
        self._require_gripper()
        return await self._transact(self._read_gripper_hook)

    async def joints_without_torque(self) -> list[str]:
        """The joints whose servos say their torque is off: a servo that rebooted by itself
        (its RAM back at the defaults) answers again limp. :class:`BusStateError` from a
        backend that cannot read it."""
        return await self._transact(self._torque_off_hook)

    # -- shared policy --------------------------------------------------------------------

    def _check_open(self) -> None:
        if self._state is BusState.FAILED:
            raise BusFailedError("the bus failed (link lost); close it and open it again")
        if self._state is BusState.CLOSED:
            raise BusStateError("the bus is not open")

    def _require_mode(self, *modes: OperatingMode) -> None:
        if self._mode not in modes:
            wanted = " or ".join(mode.value for mode in modes)
            have = "unknown" if self._mode is None else self._mode.value
            raise BusStateError(f"this command needs {wanted} mode; the bus is in {have} mode")

    def _require_gripper(self) -> GripperConfig:
        if self._gripper is None:
            raise BusStateError("this bus has no gripper configured")
        return self._gripper

    def _joint_commands(self, values: Mapping[str, float]) -> dict[JointConfig, float]:
        unknown = sorted(set(values) - set(self._joints))
        if unknown:
            raise ValueError(f"unknown joint(s) {unknown}; joints are {list(self._joints)}")
        if not values:
            raise ValueError("no joint given")
        return {self._joints[name]: float(value) for name, value in values.items()}

    def _limit_torque(self, joint: str, limit_n_m: float) -> None:
        """Lower a joint's torque limit (for backends: e.g. to the servo's current limit)."""
        self._torque_max[joint] = min(self._torque_max[joint], limit_n_m)

    async def _transact(
        self, hook: Callable[_P, Awaitable[_T]], *args: _P.args, **kwargs: _P.kwargs
    ) -> _T:
        """``await hook(*args, **kwargs)`` under the bus lock, with the failure policy: a
        link failure (timeout, garbage) counts toward FAILED, any other outcome resets
        the count."""
        self._check_open()
        async with self._lock:
            self._check_open()
            try:
                result = await hook(*args, **kwargs)
            except (BusTimeoutError, CommunicationError) as error:
                self._failures += 1
                if self._failures >= self._max_failures:
                    self._state = BusState.FAILED
                    error.add_note(
                        f"{self._failures} link failures in a row: the bus is marked failed "
                        "and the safe state was attempted"
                    )
                    await self._safe_state_logged()
                raise
            except ArmDriverError:
                self._failures = 0
                raise
            self._failures = 0
            return result

    # -- backend hooks --------------------------------------------------------------------

    @abc.abstractmethod
    async def _open_hook(self) -> tuple[OperatingMode | None, bool | None]:
        """Open the link, check every servo; return the joints' mode and torque state."""

    @abc.abstractmethod
    async def _close_hook(self) -> None:
        """Close the link; called once per open, also after a failed open."""

    @abc.abstractmethod
    async def _set_torque_hook(self, enabled: bool) -> None:
        """Turn torque on or off for the joints and the gripper."""

    @abc.abstractmethod
    async def _set_mode_hook(self, mode: OperatingMode) -> None:
        """Set the joints' operating mode (torque is off)."""

    @abc.abstractmethod
    async def _write_torques_hook(self, torques_n_m: Mapping[JointConfig, float]) -> None:
        """Send joint torques [N m], already checked."""

    @abc.abstractmethod
    async def _write_positions_hook(self, positions_rad: Mapping[JointConfig, float]) -> None:
        """Send joint angles [rad], already checked."""

    @abc.abstractmethod
    async def _read_states_hook(self) -> dict[str, JointState]:
        """Read every joint's state in one transaction, in joint order."""

    @abc.abstractmethod
    async def _write_gripper_hook(self, servo_angle_rad: float) -> None:
        """Send the gripper servo's goal shaft angle [rad]."""

    async def _read_gripper_hook(self) -> GripperState:
        """Read the gripper servo's position and current (default: not supported)."""
        raise BusStateError(f"{type(self).__name__} cannot read the gripper's state")

    async def _torque_off_hook(self) -> list[str]:
        """Names of the joints whose servos report torque off (default: not supported)."""
        raise BusStateError(f"{type(self).__name__} cannot read the servos' torque state")

    @abc.abstractmethod
    async def _safe_state_hook(self) -> None:
        """Best effort: limp joints in current or unknown mode (see the module docstring)."""

    @classmethod
    async def scan(cls, device: str, ids: Sequence[int], **options: Any) -> list[DeviceInfo]:
        """Find the servos on a bus without opening it for control (bench bring-up).

        Raises
        ------
        BackendUnavailableError
            The backend cannot scan.
        """
        raise BackendUnavailableError(f"{cls.__name__} cannot scan a bus")

    @classmethod
    def options_from_url(cls, options: Mapping[str, str]) -> dict[str, Any]:
        """Convert a URL's query options to constructor keywords; reject unknown ones."""
        if options:
            raise ValueError(f"{cls.__name__} takes no URL options, got {sorted(options)}")
        return {}


_BACKENDS: dict[str, str] = {
    "dronecan": "arm_driver.dronecan.bus:DroneCanBus",
    "dynamixel": "arm_driver.dynamixel.bus:DynamixelBus",
}


def register_backend(name: str, target: str) -> None:
    """Register a backend: URL scheme ``name`` -> ``"module:Class"`` (imported when used)."""
    module, _, cls = target.partition(":")
    if not name.isidentifier() or not module or not cls:
        raise ValueError(f"bad backend registration {name!r} -> {target!r}")
    _BACKENDS[name.lower()] = target


def available_backends() -> tuple[str, ...]:
    """Names of the registered backends."""
    return tuple(sorted(_BACKENDS))


class BackendClass(Protocol):
    """What the registry gives: a backend's class, made from a device and the joints.

    Every backend's constructor takes ``(device, joints, *, gripper=None, **options)``,
    its own keywords being the ``options`` (python-can's ``Bus(channel, **kwargs)``
    contract); the base class's constructor, which has no device, is not that contract.
    """

    def __call__(
        self,
        device: str,
        joints: Sequence[JointConfig],
        *,
        gripper: GripperConfig | None = None,
        **options: Any,
    ) -> ArmBus: ...

    async def scan(self, device: str, ids: Sequence[int], **options: Any) -> list[DeviceInfo]: ...

    def options_from_url(self, options: Mapping[str, str]) -> dict[str, Any]: ...


def backend_class(name: str) -> BackendClass:
    """Import and return the backend registered as ``name``.

    Raises
    ------
    BackendUnavailableError
        No such backend, or one whose dependencies are not installed.
    """
    name = name.lower()
    if name not in _BACKENDS:
        raise BackendUnavailableError(
            f"unknown bus backend {name!r}; available: {', '.join(available_backends())}"
        )
    module, _, cls = _BACKENDS[name].partition(":")
    try:
        found: type[ArmBus] = getattr(importlib.import_module(module), cls)
    except ImportError as error:
        raise BackendUnavailableError(
            f"backend {name!r} cannot be imported ({error}); is its dependency installed?"
        ) from error
    # A backend's own keywords make its constructor's signature differ from every other's,
    # so no class is an instance of the protocol for the type checker: the registry's
    # contract (see BackendClass) is what this cast states.
    return cast(BackendClass, found)


def open_bus(
    url: str,
    joints: Sequence[JointConfig],
    *,
    gripper: GripperConfig | None = None,
    **options: Any,
) -> ArmBus:
    """Make the bus a URL names; it opens with ``async with`` (or ``await bus.open()``).

    Parameters
    ----------
    url
        ``backend://device?option=value&...``, e.g.
        ``dynamixel:///dev/ttyUSB0?baud=1000000``.
    joints
        The arm's joints.
    gripper
        The gripper's servo, if any.
    **options
        Backend keywords; one also given in the URL is an error.

    Raises
    ------
    BackendUnavailableError
        Unknown or not yet implemented backend.
    ValueError
        Bad URL, unknown or conflicting options, bad joint configuration.
    """
    parsed = parse_bus_url(url)
    cls = backend_class(parsed.backend)
    from_url = cls.options_from_url(parsed.options)
    both = sorted(set(from_url) & set(options))
    if both:
        raise ValueError(f"option(s) {both} given both in the URL and as keywords")
    return cls(parsed.device, joints, gripper=gripper, **from_url, **options)


async def scan_bus(url: str, ids: Sequence[int] | None = None) -> list[DeviceInfo]:
    """The servos answering on the bus a URL names, in id order.

    Parameters
    ----------
    url
        Bus URL, as for :func:`open_bus`.
    ids
        Ids to look for; None: every id the backend can address.

    Raises
    ------
    BackendUnavailableError, ValueError
        As :func:`open_bus`.
    ArmDriverError
        The link cannot be opened.
    """
    parsed = parse_bus_url(url)
    cls = backend_class(parsed.backend)
    return await cls.scan(
        parsed.device,
        list(range(256)) if ids is None else list(ids),
        **cls.options_from_url(parsed.options),
    )

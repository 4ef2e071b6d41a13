"""The backend-neutral bus: URLs, the registry, the lifecycle and the shared policy.

Policy is tested through a recording backend defined here, so what the base class
decides (limits, modes, failure counting) is checked without any transport.
"""

from __future__ import annotations

import asyncio
import math
import subprocess
import sys
from collections.abc import Awaitable, Callable, Mapping
from typing import Any

import pytest

from arm_driver.bus import (
    ArmBus,
    BackendUnavailableError,
    BusFailedError,
    BusState,
    BusStateError,
    GripperConfig,
    JointConfig,
    JointState,
    OperatingMode,
    available_backends,
    backend_class,
    open_bus,
    open_buses,
    register_backend,
)
from arm_driver.errors import BusTimeoutError, InstructionError, LimitError
from arm_driver.url import BusUrl, parse_bus_url

JOINTS = (
    JointConfig("shoulder", 1, 1.78, torque_max_n_m=2.0, position_min_rad=-1.0),
    JointConfig("elbow", 2, 1.78, torque_max_n_m=1.0, direction=-1, zero_offset_rad=0.25),
)


def run(body: Callable[[], Awaitable[Any]], timeout_s: float = 5.0) -> Any:
    async def bounded() -> Any:
        async with asyncio.timeout(timeout_s):
            return await body()

    return asyncio.run(bounded())


pytestmark = pytest.mark.usefixtures("no_leaked_bus")


class RecordingBus(ArmBus):
    """A backend that records what the base class lets through to the hooks."""

    def __init__(self, device: str, joints: Any, *, gripper: Any = None, **options: Any) -> None:
        super().__init__(joints, gripper=gripper, max_consecutive_failures=2)
        self.device = device
        self.options = options
        self.sent: list[tuple[str, Any]] = []
        self.opened = 0
        self.closed = 0
        self.fail_with: Exception | None = None

    async def _open_hook(self) -> tuple[OperatingMode | None, bool | None]:
        self.opened += 1
        return None, False

    async def _close_hook(self) -> None:
        self.closed += 1

    async def _hook(self, name: str, value: Any) -> Any:
        if self.fail_with is not None:
            raise self.fail_with
        self.sent.append((name, value))

    async def _set_torque_hook(self, enabled: bool) -> None:
        await self._hook("torque", enabled)

    async def _set_mode_hook(self, mode: OperatingMode) -> None:
        await self._hook("mode", mode)

    async def _write_torques_hook(self, torques_n_m: Mapping[JointConfig, float]) -> None:
        await self._hook("torques", {joint.name: t for joint, t in torques_n_m.items()})

    async def _write_positions_hook(self, positions_rad: Mapping[JointConfig, float]) -> None:
        await self._hook("positions", {joint.name: q for joint, q in positions_rad.items()})

    async def _read_states_hook(self) -> dict[str, JointState]:
        await self._hook("read", None)
        return {j.name: JointState(j.name, 0.0, 0.0, 0.0, 0.0) for j in self.joints}

    async def _write_gripper_hook(self, servo_angle_rad: float) -> None:
        await self._hook("gripper", servo_angle_rad)

    async def _safe_state_hook(self) -> None:
        self.sent.append(("safe", None))


@pytest.fixture
def recording_backend() -> str:
    """Register :class:`RecordingBus` (idempotent; it stays registered for the session)."""
    register_backend("recording", f"{__name__}:RecordingBus")
    return "recording"


# -- URLs -------------------------------------------------------------------------------


def test_dynamixel_url_with_a_device_path() -> None:
    url = parse_bus_url("dynamixel:///dev/ttyUSB0?baud=1000000")
    assert url == BusUrl("dynamixel", "/dev/ttyUSB0", {"baud": "1000000"})


def test_dronecan_url_with_an_interface_name() -> None:
    url = parse_bus_url("DroneCAN://can0?interface=socketcan&node_id=10")
    assert url.backend == "dronecan"
    assert url.device == "can0"
    assert dict(url.options) == {"interface": "socketcan", "node_id": "10"}


@pytest.mark.parametrize(
    ("url", "match"),
    [
        ("/dev/ttyUSB0", "no backend"),
        ("dynamixel://", "no device"),
        ("dynamixel:///dev/ttyUSB0?baud=1&baud=2", "given twice"),
        ("dynamixel:///dev/ttyUSB0#x", "fragment"),
    ],
)
def test_bad_urls_are_refused(url: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        parse_bus_url(url)


def test_url_options_are_read_only() -> None:
    with pytest.raises(TypeError):
        parse_bus_url("dynamixel:///dev/x?baud=1").options["baud"] = "2"  # type: ignore[index]


# -- registry ---------------------------------------------------------------------------


def test_dynamixel_is_registered_and_imported_lazily() -> None:
    assert "dynamixel" in available_backends()
    from arm_driver.dynamixel.bus import DynamixelBus

    assert backend_class("dynamixel") is DynamixelBus


def test_dronecan_is_registered_and_imported_only_when_chosen() -> None:
    code = (
        "import sys, arm_driver.bus as b; assert 'dronecan' not in sys.modules; "
        "cls = b.backend_class('dronecan'); assert 'dronecan' in sys.modules; "
        "print(cls.__name__)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "DroneCanBus"


def test_dronecan_url_options_are_converted_and_unknown_ones_refused() -> None:
    bus = open_bus(
        "dronecan://can0?interface=virtual&node_id=11&timeout_ms=4&max_status_age_ms=30"
        "&open_timeout_ms=200&arming=0",
        JOINTS,
    )
    assert bus.state is BusState.CLOSED
    with pytest.raises(ValueError, match="unknown dronecan option"):
        open_bus("dronecan://can0?baud=1", JOINTS)
    with pytest.raises(ValueError, match="node_id"):
        open_bus("dronecan://can0?node_id=x", JOINTS)
    with pytest.raises(ValueError, match="node id 0 out of range"):
        open_bus("dronecan://can0?node_id=0", JOINTS)


def test_a_backend_whose_dependency_is_missing_is_unavailable() -> None:
    register_backend("missingdep", "arm_driver.no_such_module:Bus")
    with pytest.raises(BackendUnavailableError, match="cannot be imported"):
        open_bus("missingdep://x", JOINTS)


def test_unknown_backend_lists_the_known_ones() -> None:
    with pytest.raises(BackendUnavailableError, match=r"available: .*dynamixel"):
        open_bus("carrier-pigeon://coop", JOINTS)


def test_url_options_reach_the_backend_and_conflicts_are_refused(recording_backend: str) -> None:
    with pytest.raises(ValueError, match="takes no URL options"):
        open_bus(f"{recording_backend}://dev?speed=3", JOINTS)
    bus = open_bus(f"{recording_backend}://dev", JOINTS, speed=3)
    assert isinstance(bus, RecordingBus)
    assert bus.device == "dev"
    assert bus.options == {"speed": 3}


def test_dynamixel_url_options_are_converted_and_unknown_ones_refused() -> None:
    cls = backend_class("dynamixel")
    kwargs = cls.options_from_url({"baud": "57600", "timeout_margin_ms": "2", "low_latency": "0"})
    assert kwargs == {"baudrate": 57600, "timeout_margin_s": 0.002, "low_latency": False}
    with pytest.raises(ValueError, match="unknown dynamixel option"):
        cls.options_from_url({"bauds": "1"})
    with pytest.raises(ValueError, match="not valid"):
        cls.options_from_url({"baud": "fast"})
    with pytest.raises(ValueError, match="both in the URL and as keywords"):
        open_bus("dynamixel:///dev/null?baud=1", JOINTS, baudrate=2)


# -- configuration ----------------------------------------------------------------------


def test_joint_angle_mapping_round_trips() -> None:
    elbow = JOINTS[1]
    assert elbow.servo_angle_rad(0.0) == 0.25
    assert elbow.servo_angle_rad(0.5) == pytest.approx(-0.25)
    assert elbow.joint_angle_rad(elbow.servo_angle_rad(0.3)) == pytest.approx(0.3)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"direction": 0},
        {"torque_constant_n_m_per_a": 0.0},
        {"torque_max_n_m": math.inf},
        {"position_min_rad": 1.0, "position_max_rad": -1.0},
    ],
)
def test_bad_joint_configs_are_refused(kwargs: dict[str, Any]) -> None:
    base = {"name": "j", "servo_id": 1, "torque_constant_n_m_per_a": 1.0, "torque_max_n_m": 1.0}
    with pytest.raises(ValueError):
        JointConfig(**{**base, **kwargs})


def test_duplicate_names_or_ids_are_refused() -> None:
    with pytest.raises(ValueError, match="duplicate joint names"):
        RecordingBus("d", [JOINTS[0], JOINTS[0]])
    with pytest.raises(ValueError, match="duplicate servo ids"):
        RecordingBus("d", JOINTS, gripper=GripperConfig(2, 0.0, 1.0))


# -- lifecycle and policy ----------------------------------------------------------------


def test_nothing_opens_in_the_constructor_and_close_is_safe_twice() -> None:
    async def body() -> None:
        bus = RecordingBus("d", JOINTS)
        assert bus.opened == 0 and bus.state is BusState.CLOSED
        await bus.close()  # never opened: nothing to do
        async with bus:
            assert bus.opened == 1 and bus in open_buses()
        await bus.close()
        assert bus.closed == 1 and bus not in open_buses()
        with pytest.raises(BusStateError, match="not open"):
            await bus.read_joint_states()

    run(body)


def test_limits_are_checked_before_anything_is_sent() -> None:
    async def body() -> None:
        async with RecordingBus("d", JOINTS) as bus:
            await bus.set_operating_mode(OperatingMode.CURRENT)
            bus.sent.clear()
            with pytest.raises(LimitError) as caught:
                await bus.write_joint_torques({"shoulder": 0.5, "elbow": -1.2})
            assert caught.value.joint == "elbow" and caught.value.unit == "N m"
            with pytest.raises(LimitError):
                await bus.write_joint_torques({"shoulder": math.nan})
            assert bus.sent == []
            await bus.write_joint_torques({"shoulder": 2.0, "elbow": -1.0})
            assert bus.sent == [("torques", {"shoulder": 2.0, "elbow": -1.0})]

    run(body)


def test_position_limits_and_mode_checks() -> None:
    async def body() -> None:
        async with RecordingBus("d", JOINTS) as bus:
            with pytest.raises(BusStateError, match="position"):
                await bus.write_joint_positions({"shoulder": 0.0})
            await bus.set_operating_mode(OperatingMode.CURRENT_BASED_POSITION)
            with pytest.raises(LimitError, match=r"-1\.5 rad"):
                await bus.write_joint_positions({"shoulder": -1.5})
            await bus.write_joint_positions({"shoulder": -1.0})
            await bus.enable_torque()
            with pytest.raises(BusStateError, match="disable_torque"):
                await bus.set_operating_mode(OperatingMode.CURRENT)
            with pytest.raises(BusStateError, match="no gripper"):
                await bus.open_gripper()

    run(body)


def test_a_caller_can_fail_the_bus_into_its_safe_state() -> None:
    """The flight app decides a servo is lost after 0.3 s, before max_consecutive_failures."""

    async def body() -> None:
        async with RecordingBus("d", JOINTS) as bus:
            await bus.enter_safe_state()
            assert bus.state is BusState.FAILED and ("safe", None) in bus.sent
            with pytest.raises(BusFailedError):
                await bus.read_joint_states()

    run(body)


def test_link_failures_in_a_row_fail_the_bus_and_apply_the_safe_state() -> None:
    async def body() -> None:
        async with RecordingBus("d", JOINTS) as bus:
            bus.fail_with = BusTimeoutError(1, 0.004)
            with pytest.raises(BusTimeoutError):
                await bus.read_joint_states()
            bus.fail_with = InstructionError(1, 7)  # the link works: the count restarts
            with pytest.raises(InstructionError):
                await bus.read_joint_states()
            bus.fail_with = BusTimeoutError(1, 0.004)
            with pytest.raises(BusTimeoutError):
                await bus.read_joint_states()
            assert bus.state is BusState.OPEN
            with pytest.raises(BusTimeoutError) as caught:
                await bus.read_joint_states()
            assert "marked failed" in "".join(caught.value.__notes__)
            assert bus.state is BusState.FAILED and ("safe", None) in bus.sent
            with pytest.raises(BusFailedError):
                await bus.read_joint_states()
            with pytest.raises(BusFailedError):
                await bus.open()
        assert bus.state is BusState.CLOSED and bus.closed == 1

    run(body)

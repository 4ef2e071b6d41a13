"""One conformance suite for every arm bus backend (python-can back2back style).

Every test runs against each backend of `tests/arm_conformance.py`: the Dynamixel
emulator on a pty, the DroneCAN emulator on a virtual CAN bus, and real hardware when
``ARM_BUS_URL`` is set (``ARM_BUS_URL=... pytest -m hardware tests/test_arm_conformance.py``;
the arm must be free to move about +-0.5 rad around its zero and to take 0.5 N m).
Tests that need to look at or fault the device side skip on hardware.

No timed asserts: a timeout is checked through the deadline the error reports against
the configured one. Each body runs under a hard deadline, so a hang fails; a fixture
fails any test that leaves a bus open.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Awaitable, Callable, Iterator
from typing import Any

import pytest
from arm_conformance import ANGLE_TOLERANCE_RAD, HARNESSES, Harness

from arm_driver.bus import (
    ArmBus,
    BusFailedError,
    BusState,
    BusStateError,
    OperatingMode,
    UnsupportedModeError,
    open_bus,
    open_buses,
)
from arm_driver.errors import BusTimeoutError, HardwareError, HardwareErrorStatus, LimitError
from sitl.servo import Faults


def run(body: Callable[[], Awaitable[Any]], timeout_s: float = 20.0) -> Any:
    """Run an async test body; a hang fails the test instead of stalling the suite."""

    async def bounded() -> Any:
        async with asyncio.timeout(timeout_s):
            return await body()

    return asyncio.run(bounded())


async def until(condition: Callable[[], Any], timeout_s: float = 5.0) -> Any:
    """Poll ``condition`` (sync or async) until it is truthy; fail after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if asyncio.iscoroutine(value):
            value = await value
        if value:
            return value
        assert time.monotonic() < deadline, "condition not reached in time"
        await asyncio.sleep(0.005)


pytestmark = pytest.mark.usefixtures("no_leaked_bus")


@pytest.fixture(
    params=["dynamixel", "dronecan", pytest.param("hardware", marks=pytest.mark.hardware)]
)
def harness(request: pytest.FixtureRequest) -> Iterator[Harness]:
    h = HARNESSES[request.param]()
    yield h
    h.close()


def make_bus(h: Harness) -> ArmBus:
    return open_bus(h.url, h.joints, gripper=h.gripper)


async def prepare(bus: ArmBus, mode: OperatingMode) -> None:
    """Torque off, mode, torque on: the bring-up every control session starts with."""
    await bus.disable_torque()
    await bus.set_operating_mode(mode)
    await bus.enable_torque()


# -- lifecycle -------------------------------------------------------------------------


def test_open_close_twice_and_reopen(harness: Harness) -> None:
    async def body() -> None:
        bus = make_bus(harness)
        assert bus.state is BusState.CLOSED
        await bus.open()
        await bus.open()  # no-op
        assert bus.state is BusState.OPEN and bus in open_buses()
        await bus.close()
        await bus.close()
        assert bus.state is BusState.CLOSED and bus not in open_buses()
        with pytest.raises(BusStateError, match="not open"):
            await bus.read_joint_states()
        async with bus:
            assert len(await bus.read_joint_states()) == len(harness.joints)
        assert bus.state is BusState.CLOSED

    run(body)


def test_torque_on_and_off_reaches_every_servo(harness: Harness) -> None:
    async def body() -> None:
        async with make_bus(harness) as bus:
            await prepare(bus, OperatingMode.POSITION)
            assert bus.torque_enabled is True
            ids = [j.servo_id for j in harness.joints]
            await until(lambda: all(harness.torque_on(i) for i in ids))  # CAN: asynchronous
            await bus.disable_torque()
            assert bus.torque_enabled is False
            await until(lambda: not any(harness.torque_on(i) for i in ids))

    run(body)


def test_mode_switch_needs_torque_off_and_unsupported_modes_are_refused(harness: Harness) -> None:
    async def body() -> None:
        async with make_bus(harness) as bus:
            await prepare(bus, OperatingMode.POSITION)
            with pytest.raises(BusStateError, match="disable_torque"):
                await bus.set_operating_mode(OperatingMode.CURRENT)
            assert bus.operating_mode is OperatingMode.POSITION
            await bus.disable_torque()
            for mode in OperatingMode:
                if mode in bus.supported_modes:
                    await bus.set_operating_mode(mode)
                    assert bus.operating_mode is mode
                else:
                    before = bus.operating_mode
                    with pytest.raises(UnsupportedModeError, match=mode.value):
                        await bus.set_operating_mode(mode)
                    assert bus.operating_mode is before
            assert {OperatingMode.CURRENT, OperatingMode.POSITION} <= bus.supported_modes

    run(body)


# -- commands ---------------------------------------------------------------------------


def test_torque_write_reaches_the_device_with_direction(harness: Harness) -> None:
    async def body() -> None:
        async with make_bus(harness) as bus:
            await prepare(bus, OperatingMode.CURRENT)
            await bus.write_joint_torques({"shoulder": 0.5, "elbow": 0.3})
            shoulder, elbow = harness.joints
            step = 0.01  # XM430 goal current resolution: 2.69 mA x 1.78 N m/A
            await until(lambda: abs(harness.goal_torque_n_m(shoulder.servo_id) - 0.5) < step)
            assert harness.goal_torque_n_m(elbow.servo_id) == pytest.approx(-0.3, abs=step)
            states = await until(bus.read_joint_states)
            await until(
                lambda: _torque_read_back(bus, {"shoulder": 0.5, "elbow": 0.3}), timeout_s=2.0
            )
            assert set(states) == {"shoulder", "elbow"}
            await bus.write_joint_torques({"shoulder": 0.0, "elbow": 0.0})

    run(body)


async def _torque_read_back(bus: ArmBus, expected: dict[str, float]) -> bool:
    states = await bus.read_joint_states()
    return all(abs(states[n].torque_n_m - t) < 0.05 for n, t in expected.items())


def test_position_write_converges_with_offset_and_direction(harness: Harness) -> None:
    async def body() -> None:
        async with make_bus(harness) as bus:
            await prepare(bus, OperatingMode.POSITION)
            goal = {"shoulder": 0.4, "elbow": -0.3}
            await bus.write_joint_positions(goal)
            elbow = harness.joints[1]
            servo_goal = elbow.zero_offset_rad - 0.3 * elbow.direction
            await until(
                lambda: (
                    abs(harness.goal_angle_rad(elbow.servo_id) - servo_goal) < ANGLE_TOLERANCE_RAD
                )
            )

            async def converged() -> bool:
                states = await bus.read_joint_states()
                return all(abs(states[n].position_rad - a) < 0.01 for n, a in goal.items())

            await until(converged, timeout_s=5.0)

    run(body)


def test_states_in_si_units_with_sign_offset_and_timestamps(harness: Harness) -> None:
    async def body() -> None:
        async with make_bus(harness) as bus:
            await bus.disable_torque()
            shoulder, elbow = harness.joints
            harness.set_shaft(shoulder.servo_id, 0.7, rate_rad_s=2.0)
            harness.set_shaft(elbow.servo_id, 0.2, rate_rad_s=-2.0)
            before = time.monotonic()
            await asyncio.sleep(0.05)  # let a Status of the new state arrive
            states = await until(bus.read_joint_states)
            after = time.monotonic()
            s, e = states["shoulder"], states["elbow"]
            assert (s.name, e.name) == ("shoulder", "elbow")
            # rates decay on the rig's damping and angles drift: sign and rough size only
            assert s.position_rad == pytest.approx(0.7, abs=0.2)
            assert e.position_rad == pytest.approx(-(0.2 - 0.5), abs=0.2)
            assert 0.5 < s.velocity_rad_s < 2.1
            assert 0.5 < e.velocity_rad_s < 2.1  # direction -1: a falling shaft is a rising joint
            assert abs(s.torque_n_m) < 0.05 and abs(e.torque_n_m) < 0.05  # torque off
            for state in (s, e):
                assert before <= state.timestamp_s <= after

    run(body)


def test_limits_are_enforced_before_anything_is_sent(harness: Harness) -> None:
    async def body() -> None:
        async with make_bus(harness) as bus:
            await prepare(bus, OperatingMode.CURRENT)
            await bus.write_joint_torques({"shoulder": 0.2})
            sid = harness.joints[0].servo_id
            await until(lambda: abs(harness.goal_torque_n_m(sid) - 0.2) < 0.01)
            for bad in (2.5, -2.01, math.nan, math.inf):
                with pytest.raises(LimitError, match="nothing was sent"):
                    await bus.write_joint_torques({"shoulder": 0.1, "elbow": bad})
            with pytest.raises(LimitError):
                await bus.write_joint_torques({"shoulder": 3.0})
            with pytest.raises(ValueError, match="unknown joint"):
                await bus.write_joint_torques({"wrist": 0.1})
            with pytest.raises(BusStateError, match="position"):
                await bus.write_joint_positions({"shoulder": 0.1})
            await asyncio.sleep(0.05)
            assert harness.goal_torque_n_m(sid) == pytest.approx(0.2, abs=0.01)  # untouched
            await bus.write_joint_torques({"shoulder": 0.0})
            assert bus.state is BusState.OPEN

    run(body)


def test_gripper_open_and_close(harness: Harness) -> None:
    if harness.gripper is None:
        pytest.skip("no gripper configured")

    async def body() -> None:
        async with make_bus(harness) as bus:
            gripper = harness.gripper
            assert gripper is not None
            await bus.open_gripper()
            await until(
                lambda: (
                    abs(harness.goal_angle_rad(gripper.servo_id) - gripper.open_position_rad)
                    < ANGLE_TOLERANCE_RAD
                )
            )
            await bus.close_gripper()
            await until(
                lambda: (
                    abs(harness.goal_angle_rad(gripper.servo_id) - gripper.closed_position_rad)
                    < ANGLE_TOLERANCE_RAD
                )
            )

    run(body)


# -- faults -------------------------------------------------------------------------------


def test_missing_servo_times_out_within_the_configured_bound(harness: Harness) -> None:
    async def body() -> None:
        async with make_bus(harness) as bus:
            elbow = harness.joints[1].servo_id
            harness.set_faults(Faults(silent_ids=frozenset({elbow})))
            await asyncio.sleep(0.1)  # let the last Status age (DroneCAN keeps 50 ms)
            with pytest.raises(BusTimeoutError) as info:
                await bus.read_joint_states()
            assert info.value.servo_id == elbow
            assert 0.0 < info.value.timeout_s <= harness.timeout_bound_s
            assert bus.state is BusState.OPEN  # one failure is not a failed bus
            harness.set_faults(Faults())
            await until(bus.read_joint_states)

    run(body)


def test_damaged_replies_are_survived(harness: Harness) -> None:
    async def body() -> None:
        async with make_bus(harness) as bus:
            harness.set_faults(Faults(crc_corruption_rate=0.05, seed=7))
            reads = 0

            async def survived_damage() -> bool:
                nonlocal reads
                assert len(await bus.read_joint_states()) == 2  # retried or replaced
                reads += 1
                return reads >= 20 and harness.corrupted_replies() >= 3

            await until(survived_damage, timeout_s=10.0)
            assert bus.state is BusState.OPEN

    run(body)


def test_hardware_error_is_raised_with_decoded_bits(harness: Harness) -> None:
    async def body() -> None:
        async with make_bus(harness) as bus:
            sid = harness.joints[0].servo_id
            harness.inject_overload(sid)

            async def raised() -> HardwareError | None:
                try:
                    await bus.read_joint_states()
                except HardwareError as error:
                    return error
                return None

            error = await until(raised, timeout_s=3.0)
            assert error.servo_id == sid
            assert HardwareErrorStatus.OVERLOAD in harness.decoded_bits(error)
            assert not harness.torque_on(sid)  # the servo's own shutdown
            assert bus.state is BusState.OPEN  # the link works: reported, not acted on

    run(body)


def test_a_silent_host_leaves_current_mode_joints_without_torque(harness: Harness) -> None:
    """The device's own timeout stops a torque command when the host itself dies."""
    if harness.command_timeout_s is None:
        pytest.skip(f"{harness.name}: the bus URL arms no command timeout")

    async def body() -> None:
        async with make_bus(harness) as bus:
            await prepare(bus, OperatingMode.CURRENT)
            await bus.write_joint_torques({"shoulder": 0.4, "elbow": 0.0})
            await until(lambda: _torque_read_back(bus, {"shoulder": 0.4}), timeout_s=2.0)
            await asyncio.sleep(3 * harness.command_timeout_s + 0.1)  # not a word
            states = await bus.read_joint_states()
            assert abs(states["shoulder"].torque_n_m) < 0.05
            await bus.disable_torque()

    run(body)


def test_bus_failure_fails_the_bus_and_limps_current_mode_joints(harness: Harness) -> None:
    async def body() -> None:
        bus = make_bus(harness)
        async with bus:
            await prepare(bus, OperatingMode.CURRENT)
            await bus.write_joint_torques({"shoulder": 0.4, "elbow": 0.4})
            ids = [j.servo_id for j in harness.joints]
            await until(lambda: all(abs(harness.goal_torque_n_m(i)) > 0.3 for i in ids))
            harness.set_faults(Faults(silent_ids=frozenset(ids)))
            await asyncio.sleep(0.1)
            for _ in range(3):
                with pytest.raises(BusTimeoutError):
                    await bus.read_joint_states()
            assert bus.state is BusState.FAILED
            await until(lambda: not any(harness.torque_on(i) for i in ids), timeout_s=2.0)
            assert all(harness.goal_torque_n_m(i) == 0.0 for i in ids)
            with pytest.raises(BusFailedError):
                await bus.write_joint_torques({"shoulder": 0.1})
            with pytest.raises(BusFailedError):
                await bus.open()
        assert bus.state is BusState.CLOSED

    run(body)

"""The Dynamixel backend end to end: our client against the XM430 emulator on a pty.

Every test body runs under a hard deadline (:func:`run`), so a hang is a failure, and an
autouse fixture fails any test that leaves a bus open.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import time
from collections.abc import Awaitable, Callable, Iterator
from typing import Any

import pytest

from arm_driver.bus import (
    BusFailedError,
    BusState,
    BusStateError,
    GripperConfig,
    JointConfig,
    OperatingMode,
    open_bus,
)
from arm_driver.dynamixel import control_table as ct
from arm_driver.dynamixel import units
from arm_driver.dynamixel.bus import DynamixelBus
from arm_driver.errors import (
    ArmDriverError,
    BusTimeoutError,
    CommunicationError,
    HardwareError,
    HardwareErrorStatus,
    InstructionError,
    LimitError,
    StatusError,
)
from sitl.servo import Faults, PtyServoBus, XM430Servo

KT = 1.78
JOINTS = (
    JointConfig("shoulder", 1, KT, torque_max_n_m=2.0),
    JointConfig("elbow", 2, KT, torque_max_n_m=1.5, direction=-1, zero_offset_rad=0.5),
)
GRIPPER = GripperConfig(3, open_position_rad=0.8, closed_position_rad=-0.2)
RELAXED_MARGIN_S = 0.05
"""Timeout margin for tests about behaviour, not timing: robust on a loaded machine."""


def run(body: Callable[[], Awaitable[Any]], timeout_s: float = 10.0) -> Any:
    """Run an async test body; a hang fails the test instead of stalling the suite."""

    async def bounded() -> Any:
        async with asyncio.timeout(timeout_s):
            return await body()

    return asyncio.run(bounded())


def until(condition: Callable[[], bool], timeout_s: float = 2.0) -> None:
    """Wait for the emulator thread to have handled unanswered packets."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "the emulator did not get there in time"
        time.sleep(0.001)


pytestmark = pytest.mark.usefixtures("no_leaked_bus")


@pytest.fixture
def sim() -> Iterator[PtyServoBus]:
    with PtyServoBus({i: XM430Servo(i) for i in (1, 2, 3)}) as bus:
        yield bus


def make_bus(sim: PtyServoBus, **options: Any) -> DynamixelBus:
    options.setdefault("timeout_margin_s", RELAXED_MARGIN_S)
    return DynamixelBus(sim.device, JOINTS, gripper=GRIPPER, **options)


def test_open_via_url_pings_and_learns_the_servos(sim: PtyServoBus) -> None:
    async def body() -> None:
        bus = open_bus(f"dynamixel://{sim.device}?baud=1000000&timeout_margin_ms=50", JOINTS)
        assert isinstance(bus, DynamixelBus)
        async with bus:
            assert bus.state is BusState.OPEN
            assert bus.operating_mode is OperatingMode.POSITION  # factory default
            assert bus.torque_enabled is False
            # Current Limit 1193 x 2.69 mA x 1.78 N m/A = 5.7 N m: the config's limits hold
            assert bus.torque_limit_n_m("shoulder") == 2.0
        assert bus.state is BusState.CLOSED
        await bus.close()

    run(body)


def test_wrong_model_number_refuses_to_open(sim: PtyServoBus) -> None:
    async def body() -> None:
        bus = make_bus(sim, model_number=1060)
        with pytest.raises(ArmDriverError, match="model 1020, expected 1060"):
            await bus.open()
        assert bus.state is BusState.CLOSED

    run(body)


def test_torque_on_and_off_reaches_every_servo(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim) as bus:
            await bus.enable_torque()
            with sim.lock:
                assert all(servo.torque_enabled for servo in sim.servos.values())
            await bus.disable_torque()
            with sim.lock:
                assert not any(servo.torque_enabled for servo in sim.servos.values())

    run(body)


def test_torque_off_reaches_every_servo_even_past_one_that_does_not_answer(
    sim: PtyServoBus,
) -> None:
    async def body() -> None:
        async with make_bus(sim) as bus:
            await bus.enable_torque()
            sim.set_faults(Faults(silent_ids=frozenset({1})))
            with pytest.raises(BusTimeoutError) as info:
                await bus.disable_torque()
            assert info.value.servo_id == 1
            with sim.lock:  # the silent servo carried it out too
                assert not any(servo.torque_enabled for servo in sim.servos.values())
            sim.set_faults(Faults())

    run(body)


def test_operating_mode_is_written_with_torque_off(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim) as bus:
            await bus.set_operating_mode(OperatingMode.CURRENT)
            with sim.lock:
                assert sim.servos[1].get(ct.OPERATING_MODE) == ct.OperatingMode.CURRENT
                assert sim.servos[2].get(ct.OPERATING_MODE) == ct.OperatingMode.CURRENT
                assert sim.servos[3].get(ct.OPERATING_MODE) == ct.OperatingMode.POSITION
            await bus.enable_torque()
            with pytest.raises(BusStateError, match="disable_torque"):
                await bus.set_operating_mode(OperatingMode.POSITION)

    run(body)


def test_servo_refuses_eeprom_write_while_its_torque_is_on(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim) as bus:
            with sim.lock:  # torque turned on behind the bus's back
                sim.servos[2].write(ct.TORQUE_ENABLE.address, b"\x01")
            with pytest.raises(InstructionError) as caught:
                await bus.set_operating_mode(OperatingMode.CURRENT)
            assert caught.value.error is StatusError.ACCESS
            assert caught.value.servo_id == 2
            assert bus.operating_mode is None
            with sim.lock:
                assert sim.servos[2].get(ct.OPERATING_MODE) == ct.OperatingMode.POSITION

    run(body)


def test_torques_become_goal_currents_with_direction(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim) as bus:
            with pytest.raises(BusStateError, match="current mode"):
                await bus.write_joint_torques({"shoulder": 0.1})
            await bus.set_operating_mode(OperatingMode.CURRENT)
            await bus.enable_torque()
            await bus.write_joint_torques({"shoulder": 0.89, "elbow": 0.445})
            await bus.read_joint_states()  # a round trip: the sync write was handled
            with sim.lock:
                assert sim.servos[1].get(ct.GOAL_CURRENT) == units.a_to_current_units(0.5)
                assert sim.servos[2].get(ct.GOAL_CURRENT) == units.a_to_current_units(-0.25)
            await bus.disable_torque()

    run(body)


def test_limits_are_enforced_before_anything_is_sent(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim) as bus:
            await bus.set_operating_mode(OperatingMode.CURRENT)
            await bus.enable_torque()
            for bad in (2.5, -2.01, math.nan):
                with pytest.raises(LimitError):
                    await bus.write_joint_torques({"elbow": 0.1, "shoulder": bad})
            await bus.read_joint_states()
            with sim.lock:
                assert sim.servos[2].get(ct.GOAL_CURRENT) == 0  # elbow untouched too
            with pytest.raises(ValueError, match="unknown joint"):
                await bus.write_joint_torques({"wrist": 0.1})
            await bus.disable_torque()

    run(body)


def test_measured_torque_constants_take_over_the_conversions(sim: PtyServoBus) -> None:
    """After set_torque_constants a torque command is the current at the new constant, for
    the named joint only; an unknown joint or a bad constant changes nothing."""

    async def body() -> None:
        async with make_bus(sim) as bus:
            await bus.set_operating_mode(OperatingMode.CURRENT)
            await bus.enable_torque()
            for bad in ({"wrist": 1.5}, {"shoulder": 1.5, "elbow": -1.0}):
                with pytest.raises(ValueError):
                    bus.set_torque_constants(bad)
            assert [j.torque_constant_n_m_per_a for j in bus.joints] == [KT, KT]
            bus.set_torque_constants({"shoulder": 1.5})
            assert [j.torque_constant_n_m_per_a for j in bus.joints] == [1.5, KT]
            await bus.write_joint_torques({"shoulder": 0.6, "elbow": 0.6})
            await bus.read_joint_states()
            with sim.lock:
                assert sim.servos[1].get(ct.GOAL_CURRENT) == units.a_to_current_units(0.6 / 1.5)
                assert sim.servos[2].get(ct.GOAL_CURRENT) == units.a_to_current_units(-0.6 / KT)
            await bus.disable_torque()

    run(body)


def test_positions_with_zero_offset_and_direction(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim) as bus:
            await bus.write_joint_positions({"shoulder": 0.3, "elbow": 0.2})
            await bus.read_joint_states()
            with sim.lock:
                assert sim.servos[1].get(ct.GOAL_POSITION) == units.rad_to_ticks(0.3)
                assert sim.servos[2].get(ct.GOAL_POSITION) == units.rad_to_ticks(0.5 - 0.2)
            with pytest.raises(LimitError):
                await bus.write_joint_positions({"shoulder": 3.5})

    run(body)


def test_current_based_position_mode_caps_goal_current_at_the_torque_limit(
    sim: PtyServoBus,
) -> None:
    async def body() -> None:
        async with make_bus(sim) as bus:
            await bus.set_operating_mode(OperatingMode.CURRENT_BASED_POSITION)
            await bus.read_joint_states()
            with sim.lock:
                assert sim.servos[1].get(ct.GOAL_CURRENT) == units.a_to_current_units(2.0 / KT)
                assert sim.servos[2].get(ct.GOAL_CURRENT) == units.a_to_current_units(-1.5 / KT)

    run(body)


def test_joint_states_in_si_units_with_sign_offset_and_timestamp(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim) as bus:
            await bus.set_operating_mode(OperatingMode.CURRENT)
            await bus.enable_torque()
            await bus.write_joint_torques({"shoulder": -0.89, "elbow": 0.0})
            await bus.read_joint_states()  # a round trip: the sync write was handled
            with sim.lock:
                sim.servos[1].set_state(-0.4, -1.2)
                sim.servos[2].set_state(0.7, 0.6)
                for servo in sim.servos.values():
                    servo.step(0.05)
            before = time.monotonic()
            states = await bus.read_joint_states()
            assert list(states) == ["shoulder", "elbow"]
            shoulder, elbow = states["shoulder"], states["elbow"]
            tick, rate_unit = units.RAD_PER_TICK, units.VELOCITY_RAD_S_PER_UNIT
            assert shoulder.position_rad == pytest.approx(-0.4, abs=tick)
            assert shoulder.velocity_rad_s == pytest.approx(-1.2, abs=rate_unit)
            assert shoulder.torque_n_m == pytest.approx(-0.89, abs=KT * units.CURRENT_A_PER_UNIT)
            assert elbow.position_rad == pytest.approx(-(0.7 - 0.5), abs=tick)
            assert elbow.velocity_rad_s == pytest.approx(-0.6, abs=rate_unit)
            assert before <= shoulder.timestamp_s == elbow.timestamp_s <= time.monotonic()
            await bus.disable_torque()

    run(body)


def test_measured_torque_is_the_links_the_calibrated_friction_subtracted(
    sim: PtyServoBus,
) -> None:
    """Kt * current less b * rate + Fc * sign(rate), at the rate of the same read."""
    b, fc = 0.05, 0.02
    joints = tuple(
        dataclasses.replace(j, viscous_friction_n_m_s_per_rad=b, coulomb_friction_n_m=fc)
        for j in JOINTS
    )

    async def body() -> None:
        async with DynamixelBus(sim.device, joints, timeout_margin_s=RELAXED_MARGIN_S) as bus:
            await bus.set_operating_mode(OperatingMode.CURRENT)
            await bus.enable_torque()
            await bus.write_joint_torques({"shoulder": 0.89, "elbow": 0.89})
            await bus.read_joint_states()  # a round trip: the sync write was handled
            with sim.lock:
                sim.servos[1].set_state(0.0, 1.2)  # shoulder moving up
                sim.servos[2].set_state(0.5, 0.0)  # elbow at rest
                for servo in sim.servos.values():
                    servo.step(0.05)
            states = await bus.read_joint_states()
            rate = states["shoulder"].velocity_rad_s
            assert rate == pytest.approx(1.2, abs=units.VELOCITY_RAD_S_PER_UNIT)
            step = KT * units.CURRENT_A_PER_UNIT
            assert states["shoulder"].torque_n_m == pytest.approx(0.89 - b * rate - fc, abs=step)
            assert states["elbow"].torque_n_m == pytest.approx(0.89, abs=step)  # no friction
            await bus.disable_torque()

    run(body)


def test_profile_velocity_is_written_per_joint_and_checked(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim) as bus:
            await bus.set_profile_velocity({"shoulder": 1.5, "elbow": 1e-4})
            assert sim.servos[1].get(ct.PROFILE_VELOCITY) == units.rad_s_to_velocity_units(1.5)
            assert sim.servos[2].get(ct.PROFILE_VELOCITY) == 1  # slow, but not 0 (none)
            await bus.set_profile_velocity({"elbow": 0.0})
            assert sim.servos[2].get(ct.PROFILE_VELOCITY) == 0
            for bad in (-1.0, math.nan, 1e4):
                with pytest.raises(ValueError, match="profile velocity"):
                    await bus.set_profile_velocity({"shoulder": bad})
            assert sim.servos[1].get(ct.PROFILE_VELOCITY) == units.rad_s_to_velocity_units(1.5)

    run(body)


def test_gripper_open_and_close(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim) as bus:
            await bus.close_gripper()
            with sim.lock:
                assert sim.servos[3].get(ct.GOAL_POSITION) == units.rad_to_ticks(-0.2)
            await bus.open_gripper()
            with sim.lock:
                assert sim.servos[3].get(ct.GOAL_POSITION) == units.rad_to_ticks(0.8)

    run(body)


def test_missing_servo_times_out_within_a_bounded_time(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim) as bus:
            sim.set_faults(Faults(silent_ids=frozenset({2})))
            start = time.perf_counter()
            with pytest.raises(BusTimeoutError) as caught:
                await bus.read_joint_states()
            elapsed = time.perf_counter() - start
            assert caught.value.servo_id == 2
            # line time of request and replies plus two return delays (0.5 ms each at the
            # factory setting): with the default 3 ms margin a missing servo costs < 5 ms
            assert caught.value.timeout_s - RELAXED_MARGIN_S < 0.002
            assert elapsed < 0.2  # generous: correctness, not benchmarking
            assert bus.state is BusState.OPEN

    run(body)


def test_repeated_timeouts_fail_the_bus_and_limp_current_mode_joints(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim, max_consecutive_failures=2) as bus:
            await bus.set_operating_mode(OperatingMode.CURRENT)
            await bus.enable_torque()
            await bus.write_joint_torques({"shoulder": 0.5, "elbow": 0.5})
            sim.set_faults(Faults(silent_ids=frozenset({1, 2, 3})))
            for _ in range(2):
                with pytest.raises(BusTimeoutError):
                    await bus.read_joint_states()
            assert bus.state is BusState.FAILED
            with pytest.raises(BusFailedError):
                await bus.write_joint_torques({"shoulder": 0.1})
        assert bus.state is BusState.CLOSED

    run(body)
    until(lambda: not sim.servos[2].torque_enabled)  # the safe state's unanswered writes
    with sim.lock:
        assert not sim.servos[1].torque_enabled
        assert sim.servos[1].get(ct.GOAL_CURRENT) == 0
        assert sim.servos[3].torque_enabled  # the gripper keeps its payload


def test_damaged_replies_are_retried(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim, crc_retries=3) as bus:
            sim.set_faults(Faults(crc_corruption_rate=0.15, seed=7))
            for _ in range(10):
                await bus.read_joint_states()
            assert sim.corrupted_replies > 0

    run(body)


def test_always_damaged_replies_give_a_communication_error(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim, crc_retries=2) as bus:
            sim.set_faults(Faults(crc_corruption_rate=1.0))
            start = time.perf_counter()
            with pytest.raises(CommunicationError, match="CRC"):
                await bus.read_joint_states()
            assert time.perf_counter() - start < 1.0
            assert sim.corrupted_replies == 3 * 2  # three attempts, two replies each

    run(body)


def test_overload_raises_hardware_error_with_the_decoded_bit(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim) as bus:
            await bus.set_operating_mode(OperatingMode.CURRENT)
            await bus.enable_torque()
            with sim.lock:
                sim.servos[2].inject_hardware_error(HardwareErrorStatus.OVERLOAD)
            with pytest.raises(HardwareError) as caught:
                await bus.read_joint_states()
            assert caught.value.servo_id == 2
            assert caught.value.status == HardwareErrorStatus.OVERLOAD
            assert "Overload" in str(caught.value)
            assert bus.state is BusState.OPEN  # the link works: not a bus failure

    run(body)


def test_slow_replies_within_the_margin_still_succeed(sim: PtyServoBus) -> None:
    async def body() -> None:
        async with make_bus(sim) as bus:
            sim.set_faults(Faults(reply_delay_s=0.002))
            states = await bus.read_joint_states()
            assert set(states) == {"shoulder", "elbow"}

    run(body)


def test_a_late_reply_to_a_timed_out_request_is_skipped_by_the_next_ones(
    sim: PtyServoBus,
) -> None:
    """A USB-serial adapter's latency timer (16 ms on FTDI chips by default) can deliver a
    reply after its request timed out, in the middle of the next transaction."""

    async def body() -> None:
        async with make_bus(sim, timeout_margin_s=RELAXED_MARGIN_S) as bus:
            sim.set_faults(Faults(reply_delay_s=1.5 * RELAXED_MARGIN_S))
            with pytest.raises(BusTimeoutError):
                await bus.read_gripper()  # its 10-byte reply comes 25 ms after the deadline
            sim.set_faults(Faults())
            await bus.open_gripper()  # a Write, answered with no parameters
            with sim.lock:
                assert sim.servos[3].get(ct.GOAL_POSITION) == units.rad_to_ticks(0.8)
            assert bus.stale_replies == 1
            sim.set_faults(Faults(reply_delay_s=1.5 * RELAXED_MARGIN_S))
            with pytest.raises(BusTimeoutError):
                await bus.read_gripper()
            sim.set_faults(Faults())
            states = await bus.read_joint_states()  # the late reply is from servo 3
            assert set(states) == {"shoulder", "elbow"}
            assert bus.stale_replies == 2
            assert bus.state is BusState.OPEN

    run(body)


def test_servos_that_do_not_answer_writes_still_take_them(sim: PtyServoBus) -> None:
    with sim.lock:
        for servo in sim.servos.values():
            servo.write(ct.STATUS_RETURN_LEVEL.address, b"\x01")  # Ping and Read only

    async def body() -> None:
        async with make_bus(sim) as bus:
            start = time.perf_counter()
            await bus.enable_torque()  # no reply awaited, so no timeout either
            assert time.perf_counter() - start < 0.2
            await bus.read_joint_states()
            with sim.lock:
                assert all(servo.torque_enabled for servo in sim.servos.values())
            await bus.disable_torque()

    run(body)


def test_a_servo_in_hardware_error_refuses_to_open_with_its_bits(sim: PtyServoBus) -> None:
    with sim.lock:
        sim.servos[1].inject_hardware_error(HardwareErrorStatus.OVERHEATING)

    async def body() -> None:
        bus = make_bus(sim)
        with pytest.raises(HardwareError) as caught:
            await bus.open()
        assert caught.value.status == HardwareErrorStatus.OVERHEATING
        assert bus.state is BusState.CLOSED

    run(body)


def test_watchdog_option_is_validated_and_rounded_up_to_20_ms() -> None:
    assert DynamixelBus.options_from_url({"watchdog_ms": "100"}) == {"watchdog_s": 0.1}
    for bad in ("10", "2560", "-20", "nan"):
        with pytest.raises(ValueError, match="0 \\(off\\) or 20-2540 ms"):
            open_bus(f"dynamixel:///dev/null?watchdog_ms={bad}", JOINTS)
    with pytest.raises(ValueError, match="watchdog_ms"):
        open_bus("dynamixel:///dev/null?watchdog_ms=soon", JOINTS)


def watchdogs(sim: PtyServoBus) -> dict[int, int]:
    with sim.lock:
        return {i: servo.get(ct.BUS_WATCHDOG) for i, servo in sim.servos.items()}


def test_watchdog_limps_current_mode_joints_of_a_silent_host_until_torque_is_enabled(
    sim: PtyServoBus,
) -> None:
    async def body() -> None:
        url = f"dynamixel://{sim.device}?timeout_margin_ms=50&watchdog_ms=190"
        async with open_bus(url, JOINTS, gripper=GRIPPER) as bus:
            await bus.set_operating_mode(OperatingMode.CURRENT)
            await bus.enable_torque()
            assert watchdogs(sim) == {1: 10, 2: 10, 3: 0}  # 190 ms -> 200 ms; not the gripper
            for _ in range(40):  # 0.4 s of 100 Hz control cycles keep it alive
                await bus.write_joint_torques({"shoulder": 0.89, "elbow": 0.0})
                await bus.read_joint_states()
                await asyncio.sleep(0.01)
            assert (await bus.read_joint_states())["shoulder"].torque_n_m > 0.8
            until(lambda: sim.servos[1].watchdog_tripped and sim.servos[2].watchdog_tripped)
            assert watchdogs(sim)[1] == ct.BUS_WATCHDOG_TRIPPED
            await asyncio.sleep(0.01)
            assert abs((await bus.read_joint_states())["shoulder"].torque_n_m) < 0.01
            await bus.write_joint_torques({"shoulder": 0.5})  # refused, unanswered
            await bus.read_joint_states()
            with sim.lock:
                assert sim.servos[1].get(ct.GOAL_CURRENT) == units.a_to_current_units(0.5)
                assert sim.servos[1].torque_enabled  # stopped, not torque off
            await bus.enable_torque()  # clears the trip; the old goal does not come back
            assert watchdogs(sim) == {1: 10, 2: 10, 3: 0}
            with sim.lock:
                assert sim.servos[1].get(ct.GOAL_CURRENT) == 0
            await bus.write_joint_torques({"shoulder": 0.445})
            await bus.read_joint_states()
            with sim.lock:
                assert sim.servos[1].get(ct.GOAL_CURRENT) == units.a_to_current_units(0.25)

    run(body)
    until(lambda: watchdogs(sim)[2] == 0)  # the safe state's unanswered writes
    with sim.lock:
        assert not sim.servos[1].torque_enabled and not sim.servos[1].watchdog_tripped


def test_watchdog_stays_off_in_position_mode_and_needs_firmware_38(sim: PtyServoBus) -> None:
    with sim.lock:  # left armed by an earlier session
        sim.servos[1].write(ct.BUS_WATCHDOG.address, b"\x01")

    async def body() -> None:
        async with make_bus(sim, watchdog_s=0.02) as bus:
            await bus.enable_torque()  # factory position mode
            assert watchdogs(sim) == {1: 0, 2: 0, 3: 0}
            await asyncio.sleep(0.1)
            assert not any(servo.watchdog_tripped for servo in sim.servos.values())
            await bus.disable_torque()
        with sim.lock:
            sim.servos[2].table[ct.FIRMWARE_VERSION.address] = 37
        with pytest.raises(ArmDriverError, match="servo 2 has firmware v37, without Bus"):
            await make_bus(sim, watchdog_s=0.02).open()
        async with make_bus(sim):  # without the watchdog, old firmware is fine
            pass

    run(body)


def test_hold_in_place_leaves_the_joints_holding_where_they_are_after_the_close(
    sim: PtyServoBus,
) -> None:
    async def body() -> dict[str, float]:
        url = f"dynamixel://{sim.device}?timeout_margin_ms=50&watchdog_ms=100"
        async with open_bus(url, JOINTS, gripper=GRIPPER) as bus:
            await bus.set_operating_mode(OperatingMode.CURRENT)
            await bus.enable_torque()
            assert watchdogs(sim) == {1: 5, 2: 5, 3: 0}
            states = await bus.hold_in_place()
            assert bus.operating_mode is OperatingMode.CURRENT_BASED_POSITION
            assert bus.torque_enabled is True
            return {name: state.position_rad for name, state in states.items()}

    held = run(body)
    with sim.lock:
        for joint in JOINTS:
            servo = sim.servos[joint.servo_id]
            assert servo.get(ct.OPERATING_MODE) == ct.OperatingMode.CURRENT_BASED_POSITION
            assert servo.torque_enabled  # the close leaves a position-mode joint holding
            assert servo.get(ct.BUS_WATCHDOG) == 0  # no watchdog to stop it
            goal = servo.get(ct.GOAL_POSITION)
            assert abs(goal - servo.get(ct.PRESENT_POSITION)) <= 1
            angle = joint.joint_angle_rad(units.ticks_to_rad(goal))
            assert angle == pytest.approx(held[joint.name], abs=2e-3)

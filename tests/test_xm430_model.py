"""The pure XM430-W350 model: control table rules, loops, overload, joint coupling."""

from __future__ import annotations

import math
import random

import pytest

from arm_driver.dynamixel import control_table as ct
from arm_driver.dynamixel import units
from arm_driver.dynamixel.protocol import Instruction, InstructionPacket
from arm_driver.errors import HardwareErrorStatus, StatusError
from companion.compiled import twin_reason
from sitl import vehicle_step
from sitl.servo import (
    EXAMPLE_TORQUE_CONSTANT_N_M_PER_A,
    ServoJoint,
    XM430Parameters,
    XM430Servo,
)


def write(servo: XM430Servo, entry: ct.ControlTableEntry, value: int) -> int:
    return servo.write(entry.address, entry.encode(value)).error


def settle(servo: XM430Servo, seconds: float = 0.05, dt_s: float = 1e-3) -> None:
    for _ in range(round(seconds / dt_s)):
        servo.step(dt_s)


def test_factory_control_table() -> None:
    servo = XM430Servo(4)
    assert servo.get(ct.MODEL_NUMBER) == ct.XM430_W350_MODEL_NUMBER
    assert servo.get(ct.ID) == 4
    assert servo.get(ct.OPERATING_MODE) == ct.OperatingMode.POSITION
    assert servo.get(ct.CURRENT_LIMIT) == 1193
    assert servo.get(ct.STATUS_RETURN_LEVEL) == ct.StatusReturnLevel.ALL
    assert servo.return_delay_s == pytest.approx(500e-6)
    assert servo.get(ct.GOAL_POSITION) == servo.get(ct.PRESENT_POSITION) == 2048
    assert isinstance(servo, ServoJoint)


def test_ping_reply_carries_model_and_firmware() -> None:
    reply = XM430Servo(1).handle(InstructionPacket(1, Instruction.PING))
    assert reply.error == 0
    assert int.from_bytes(reply.params[:2], "little") == ct.XM430_W350_MODEL_NUMBER
    assert len(reply.params) == 3


def test_unsupported_instruction_is_an_instruction_error() -> None:
    reply = XM430Servo(1).handle(InstructionPacket(1, Instruction.REG_WRITE, b"\x40\x00\x01"))
    assert reply.error == StatusError.INSTRUCTION


def test_eeprom_write_refused_while_torque_is_on() -> None:
    servo = XM430Servo(1)
    assert write(servo, ct.TORQUE_ENABLE, 1) == 0
    assert write(servo, ct.OPERATING_MODE, ct.OperatingMode.CURRENT) == StatusError.ACCESS
    assert servo.get(ct.OPERATING_MODE) == ct.OperatingMode.POSITION
    assert write(servo, ct.TORQUE_ENABLE, 0) == 0
    assert write(servo, ct.OPERATING_MODE, ct.OperatingMode.CURRENT) == 0
    assert servo.get(ct.OPERATING_MODE) == ct.OperatingMode.CURRENT


@pytest.mark.parametrize(
    ("address", "data", "error"),
    [
        (ct.MODEL_NUMBER.address, b"\x00\x00", StatusError.ACCESS),  # read-only
        (ct.HARDWARE_ERROR_STATUS.address, b"\x20", StatusError.ACCESS),  # read-only
        (ct.PRESENT_POSITION.address, b"\x00" * 4, StatusError.ACCESS),  # read-only
        (ct.OPERATING_MODE.address, b"\x02", StatusError.DATA_RANGE),  # no such mode
        (ct.OPERATING_MODE.address, b"\x01", StatusError.DATA_RANGE),  # velocity: not modelled
        (ct.GOAL_CURRENT.address, (1194).to_bytes(2, "little"), StatusError.DATA_LIMIT),
    ],
)
def test_bad_writes_are_refused_and_change_nothing(address: int, data: bytes, error: int) -> None:
    servo = XM430Servo(1)
    before = bytes(servo.table)
    assert servo.write(address, data).error == error
    assert bytes(servo.table) == before


def test_read_beyond_the_table_is_refused() -> None:
    assert XM430Servo(1).read(140, 10).error == StatusError.ACCESS


def test_current_mode_tracks_goal_current_with_a_lag_and_gives_kt_torque() -> None:
    servo = XM430Servo(1)
    write(servo, ct.OPERATING_MODE, ct.OperatingMode.CURRENT)
    goal = units.a_to_current_units(-0.8)
    write(servo, ct.GOAL_CURRENT, goal)
    servo.step(1e-3)
    assert servo.torque_n_m() == 0.0  # torque off: no output whatever the goal
    write(servo, ct.TORQUE_ENABLE, 1)
    servo.step(0.25e-3)  # half the 0.5 ms time constant: partway there
    assert 0 > servo.get(ct.PRESENT_CURRENT) > goal
    settle(servo)
    assert servo.get(ct.PRESENT_CURRENT) == goal
    expected_n_m = EXAMPLE_TORQUE_CONSTANT_N_M_PER_A * units.current_units_to_a(goal)
    assert servo.torque_n_m() == pytest.approx(expected_n_m, rel=1e-3)


def test_position_mode_pd_drives_toward_the_goal_and_is_current_limited() -> None:
    params = XM430Parameters(position_kp_a_per_rad=4.0, position_kd_a_s_per_rad=0.5)
    servo = XM430Servo(1, params)
    write(servo, ct.GOAL_POSITION, units.rad_to_ticks(0.1))
    write(servo, ct.TORQUE_ENABLE, 1)
    servo.set_state(0.0, 0.2)
    expected = 4.0 * units.ticks_to_rad(units.rad_to_ticks(0.1)) - 0.5 * 0.2
    assert servo.commanded_current_a() == pytest.approx(expected)
    write(servo, ct.GOAL_POSITION, units.rad_to_ticks(3.0))
    limit_a = units.current_units_to_a(1193)
    assert servo.commanded_current_a() == pytest.approx(limit_a)  # 11.9 A clamped to 3.2 A
    write(servo, ct.GOAL_POSITION, units.rad_to_ticks(-3.0))
    assert servo.commanded_current_a() == pytest.approx(-limit_a)


def test_current_based_position_limits_current_to_the_goal_current() -> None:
    servo = XM430Servo(1)
    write(servo, ct.OPERATING_MODE, ct.OperatingMode.CURRENT_BASED_POSITION)
    write(servo, ct.GOAL_CURRENT, units.a_to_current_units(0.3))
    write(servo, ct.GOAL_POSITION, units.rad_to_ticks(-1.0))
    write(servo, ct.TORQUE_ENABLE, 1)
    assert servo.commanded_current_a() == pytest.approx(-units.current_units_to_a(112))


def test_closed_loop_with_a_physics_joint_settles_on_the_goal() -> None:
    """GIVEN an inertia driven through ServoJoint, WHEN the goal steps, THEN it settles."""
    servo: ServoJoint = XM430Servo(1)
    assert isinstance(servo, XM430Servo)
    write(servo, ct.GOAL_POSITION, units.rad_to_ticks(0.5))
    write(servo, ct.TORQUE_ENABLE, 1)
    inertia_kg_m2, angle, rate, dt = 0.01, 0.0, 0.0, 1e-3
    for _ in range(2000):
        servo.set_state(angle, rate)
        servo.step(dt)
        rate += servo.torque_n_m() / inertia_kg_m2 * dt
        angle += rate * dt
    assert angle == pytest.approx(0.5, abs=2 * units.RAD_PER_TICK)
    assert abs(rate) < 1e-2
    assert not servo.hardware_error


def test_profile_velocity_moves_the_shaft_to_the_goal_at_that_rate() -> None:
    """GIVEN Profile Velocity 0.5 rad/s, WHEN the goal is 1 rad away, THEN the shaft turns
    at 0.5 rad/s (the servo's own ramp) and stops on the goal; 0 again takes goals at once."""
    servo = XM430Servo(1)
    write(servo, ct.PROFILE_VELOCITY, units.rad_s_to_velocity_units(0.5))
    write(servo, ct.TORQUE_ENABLE, 1)
    write(servo, ct.GOAL_POSITION, units.rad_to_ticks(1.0))
    inertia_kg_m2, angle, rate, dt = 0.01, 0.0, 0.0, 1e-3
    rates = []
    for _ in range(3000):
        servo.set_state(angle, rate)
        servo.step(dt)
        rate += servo.torque_n_m() / inertia_kg_m2 * dt
        angle += rate * dt
        rates.append(rate)
    assert rates[1000] == pytest.approx(0.5, rel=0.02)  # mid-move, 1 s after the goal
    assert max(rates) < 0.5 * 1.1
    assert angle == pytest.approx(1.0, abs=2 * units.RAD_PER_TICK)
    write(servo, ct.PROFILE_VELOCITY, 0)
    write(servo, ct.GOAL_POSITION, units.rad_to_ticks(0.0))
    servo.step(dt)
    limit_a = units.current_units_to_a(servo.get(ct.CURRENT_LIMIT))
    assert servo.commanded_current_a() == pytest.approx(-limit_a)  # the whole step at once


def test_full_command_runs_at_the_datasheet_no_load_speed_and_draws_stall_current() -> None:
    """The voltage limit: a free shaft on the largest current command settles near 46 rpm
    (4.8 rad/s at 12 V) and not beyond, however long it runs; held still it draws the
    datasheet's 2.3 A stall current, not the 2.9 A asked (below the overload threshold)."""
    servo = XM430Servo(1)
    write(servo, ct.OPERATING_MODE, ct.OperatingMode.CURRENT)
    write(servo, ct.GOAL_CURRENT, units.a_to_current_units(2.9))
    write(servo, ct.TORQUE_ENABLE, 1)
    settle(servo)
    assert units.current_units_to_a(servo.get(ct.PRESENT_CURRENT)) == pytest.approx(2.3, rel=0.01)
    inertia_kg_m2, rate, dt = 0.002, 0.0, 1e-3
    for _ in range(5000):
        servo.set_state(0.0, rate)
        servo.step(dt)
        rate += servo.torque_n_m() / inertia_kg_m2 * dt
    assert not servo.hardware_error
    no_load_rad_s = 46.0 * 2.0 * math.pi / 60.0
    assert 0.9 * no_load_rad_s < rate < no_load_rad_s


def test_an_unpowered_shaft_is_slowed_by_the_gearbox_friction() -> None:
    """Torque off, a spinning shaft meets viscous friction (it would coast for ever
    without it): its torque opposes the rate, and a free inertia comes to rest."""
    servo = XM430Servo(1)
    servo.set_state(0.0, 2.0)
    assert servo.torque_n_m() == pytest.approx(-0.02 * 2.0)
    inertia_kg_m2, rate, dt = 0.005, 2.0, 1e-3
    for _ in range(2000):
        servo.set_state(0.0, rate)
        servo.step(dt)
        rate += servo.torque_n_m() / inertia_kg_m2 * dt
    assert 0.0 < rate < 2.0 * math.exp(-1.0)


def test_sustained_overload_sets_the_bit_shuts_down_and_needs_a_reboot() -> None:
    servo = XM430Servo(1, XM430Parameters(overload_time_s=0.2))
    write(servo, ct.OPERATING_MODE, ct.OperatingMode.CURRENT)
    write(servo, ct.GOAL_CURRENT, 1193)
    write(servo, ct.TORQUE_ENABLE, 1)
    settle(servo, 0.15)
    assert not servo.hardware_error  # not sustained long enough yet
    settle(servo, 0.1)
    assert servo.hardware_error == HardwareErrorStatus.OVERLOAD
    assert not servo.torque_enabled and servo.torque_n_m() == 0.0  # Shutdown(63) = 52
    assert servo.read(ct.HARDWARE_ERROR_STATUS.address, 1).alert
    assert write(servo, ct.TORQUE_ENABLE, 1) == StatusError.RESULT_FAIL
    servo.handle(InstructionPacket(1, Instruction.REBOOT))
    assert not servo.hardware_error
    assert write(servo, ct.TORQUE_ENABLE, 1) == 0


def test_status_return_level_and_id_are_writable_in_their_areas() -> None:
    servo = XM430Servo(1)
    assert write(servo, ct.STATUS_RETURN_LEVEL, 1) == 0
    assert servo.status_return_level == 1
    assert write(servo, ct.ID, 9) == 0
    assert servo.servo_id == 9


def test_parameters_are_validated() -> None:
    with pytest.raises(ValueError):
        XM430Parameters(torque_constant_n_m_per_a=0.0)
    with pytest.raises(ValueError):
        XM430Parameters(overload_current_fraction=1.5)
    with pytest.raises(ValueError):
        XM430Servo(253)
    assert math.isclose(EXAMPLE_TORQUE_CONSTANT_N_M_PER_A, 1.78, rel_tol=2e-3)


def armed_in_current_mode(watchdog: int, goal_a: float = 0.5) -> XM430Servo:
    """A servo in current mode applying ``goal_a`` [A], Bus Watchdog(98) = ``watchdog``."""
    servo = XM430Servo(1)
    write(servo, ct.OPERATING_MODE, ct.OperatingMode.CURRENT)
    write(servo, ct.GOAL_CURRENT, units.a_to_current_units(goal_a))
    write(servo, ct.TORQUE_ENABLE, 1)
    assert write(servo, ct.BUS_WATCHDOG, watchdog) == 0
    return servo


def test_bus_watchdog_trips_after_its_timeout_not_before_and_the_joint_goes_limp() -> None:
    servo = armed_in_current_mode(5)  # 100 ms
    settle(servo, 0.099)
    assert not servo.watchdog_tripped
    assert servo.torque_n_m() > 0.5
    settle(servo, 0.002)
    assert servo.watchdog_tripped
    reply = servo.read(ct.BUS_WATCHDOG.address, 1)
    assert ct.BUS_WATCHDOG.decode(reply.params) == ct.BUS_WATCHDOG_TRIPPED
    settle(servo, 0.01)
    assert servo.get(ct.PRESENT_CURRENT) == 0  # the current loop's lag has decayed
    assert servo.torque_n_m() == pytest.approx(0.0, abs=1e-6)
    assert servo.torque_enabled  # the e-Manual: the servo stops; Torque Enable stays


def test_bus_watchdog_is_kept_alive_by_any_instruction_and_idle_with_torque_off() -> None:
    servo = armed_in_current_mode(3)  # 60 ms
    for _ in range(20):
        settle(servo, 0.05)
        servo.read(ct.PRESENT_CURRENT.address, 2)
    servo.handle(InstructionPacket(1, Instruction.PING))
    settle(servo, 0.05)
    assert not servo.watchdog_tripped
    write(servo, ct.TORQUE_ENABLE, 0)
    settle(servo, 1.0)
    assert not servo.watchdog_tripped  # it only watches while torque is on


def test_tripped_bus_watchdog_refuses_goals_until_0_clears_it() -> None:
    servo = armed_in_current_mode(1)
    settle(servo, 0.03)
    assert servo.watchdog_tripped
    before = bytes(servo.table)
    assert write(servo, ct.GOAL_CURRENT, 0) == StatusError.DATA_RANGE
    assert write(servo, ct.GOAL_POSITION, 2048) == StatusError.DATA_RANGE
    assert write(servo, ct.BUS_WATCHDOG, 5) == StatusError.DATA_RANGE  # only 0 clears
    assert bytes(servo.table) == before
    assert write(servo, ct.BUS_WATCHDOG, 0) == 0
    assert not servo.watchdog_tripped
    assert servo.commanded_current_a() > 0.4  # the old goal applies again once cleared
    assert write(servo, ct.GOAL_CURRENT, 0) == 0


def test_bus_watchdog_range_and_reboot() -> None:
    servo = XM430Servo(1)
    assert write(servo, ct.BUS_WATCHDOG, ct.BUS_WATCHDOG_MAX) == 0
    assert servo.write(ct.BUS_WATCHDOG.address, b"\x80").error == StatusError.DATA_RANGE
    assert servo.get(ct.BUS_WATCHDOG) == ct.BUS_WATCHDOG_MAX
    servo.handle(InstructionPacket(1, Instruction.REBOOT))
    assert servo.get(ct.BUS_WATCHDOG) == 0


def test_tripped_position_mode_holds_the_angle_where_it_stopped() -> None:
    servo = XM430Servo(1)
    write(servo, ct.GOAL_POSITION, units.rad_to_ticks(0.5))
    write(servo, ct.TORQUE_ENABLE, 1)
    write(servo, ct.BUS_WATCHDOG, 1)
    servo.set_state(0.2, 0.0)
    settle(servo, 0.03)
    assert servo.watchdog_tripped
    assert servo.commanded_current_a() == pytest.approx(0.0)  # holds 0.2 rad, not 0.5
    servo.set_state(0.1, 0.0)
    assert servo.commanded_current_a() == pytest.approx(10.0 * 0.1)


def _twins(angle_rad: float) -> tuple[XM430Servo, XM430Servo]:
    """The same servo twice: the physics' compiled twin and its Python source."""
    assert twin_reason(vehicle_step) is None, twin_reason(vehicle_step)
    fast = XM430Servo(3, angle_rad=angle_rad)
    slow = XM430Servo(3, angle_rad=angle_rad, compiled=False)
    assert fast._physics is not vehicle_step and slow._physics is vehicle_step
    return fast, slow


def _same(fast: XM430Servo, slow: XM430Servo) -> None:
    assert fast.table == slow.table
    assert [v.hex() for v in fast._loop] == [v.hex() for v in slow._loop]


SETUPS = {
    "current": ((ct.OPERATING_MODE, ct.OperatingMode.CURRENT), (ct.GOAL_CURRENT, 300)),
    "position": ((ct.GOAL_POSITION, 2600),),
    "profile": ((ct.PROFILE_VELOCITY, 40), (ct.GOAL_POSITION, 1500)),
    "current-based": (
        (ct.OPERATING_MODE, ct.OperatingMode.CURRENT_BASED_POSITION),
        (ct.GOAL_CURRENT, -200),
        (ct.GOAL_POSITION, 3000),
    ),
    "watchdog": (
        (ct.OPERATING_MODE, ct.OperatingMode.CURRENT),
        (ct.BUS_WATCHDOG, 2),
        (ct.GOAL_CURRENT, 900),
    ),
    "overload": ((ct.CURRENT_LIMIT, 400), (ct.GOAL_POSITION, 4000)),
    "torque off": (),
}


@pytest.mark.parametrize("setup", SETUPS)
def test_the_compiled_step_is_the_python_step_bit_for_bit(setup: str) -> None:
    """set_state (or couple, every other step) and step, compiled and in Python, over 3 s
    of a moving shaft with a time step that changes: the same control table and loop state
    after every call (the watchdog trips, the overload shuts down, the profile ramps)."""
    rng = random.Random(setup)
    fast, slow = _twins(0.3)
    for servo in (fast, slow):
        if setup != "torque off":
            for entry, value in SETUPS[setup]:
                if entry.address < ct.TORQUE_ENABLE.address:
                    assert write(servo, entry, value) == 0
            assert write(servo, ct.TORQUE_ENABLE, 1) == 0
            for entry, value in SETUPS[setup]:
                if entry.address >= ct.TORQUE_ENABLE.address:
                    assert write(servo, entry, value) == 0
    angle, rate = 0.3, 0.0
    for i in range(3000):
        rate += rng.gauss(0.0, 0.3)
        angle += rate * 1e-3
        dt = 1e-3 if i < 2000 else 2e-3
        if i % 2:
            torque = fast.couple(angle, rate)
            assert torque == slow.couple(angle, rate) == fast.torque_n_m()
        else:
            for servo in (fast, slow):
                servo.set_state(angle, rate)
            assert fast.torque_n_m() == slow.torque_n_m()
        for servo in (fast, slow):
            servo.step(dt)
        assert fast.commanded_current_a() == slow.commanded_current_a()
        _same(fast, slow)
    if setup == "overload":
        assert fast.hardware_error & HardwareErrorStatus.OVERLOAD
    if setup == "watchdog":
        assert fast.watchdog_tripped


def test_the_compiled_step_refuses_what_python_refuses() -> None:
    fast, slow = _twins(0.0)
    for servo in (fast, slow):
        with pytest.raises(ValueError):
            servo.set_state(math.nan, 0.0)
        with pytest.raises(ValueError):
            servo.set_state(1e12, 0.0)
        with pytest.raises(ValueError):
            servo.couple(0.0, math.inf)
        with pytest.raises(ValueError):
            servo.step(-1e-3)
    _same(fast, slow)

"""The arm on a held base (``sitl.servo.arm_stand``): physics, servo coupling, real time."""

from __future__ import annotations

import asyncio
import math
import time
from pathlib import Path

import numpy as np
import pytest

from arm_driver.bus import OperatingMode, open_bus
from arm_driver.dynamixel import control_table as ct
from arm_driver.dynamixel import units
from companion.config import arm_bus_configs
from companion.model import ManipulatorModel
from sitl.scenario import load_scenario
from sitl.servo.arm_stand import ArmStand, held_base_arm

CONFIG = Path(__file__).parent.parent / "configs" / "px4_sih_pickup.toml"


@pytest.fixture(scope="module")
def scenario():
    return load_scenario(CONFIG)


def _put(servo, entry: ct.ControlTableEntry, value: int) -> None:
    """Write a control-table entry as a host's Write instruction would."""
    reply = servo.write(entry.address, int(value).to_bytes(entry.size, "little", signed=True))
    assert reply.error == 0


def _run(stand: ArmStand, seconds: float) -> None:
    for _ in range(round(seconds / stand.dt_s)):
        stand.step()


def test_joint_accelerations_are_the_fixed_base_rows_of_the_model(scenario):
    # GIVEN ArmDynamics on the held base and companion.model (derived independently)
    arm = held_base_arm(scenario, 1e-3)
    model = ManipulatorModel.from_config(scenario)
    link2 = arm.link2_empty.theta
    theta = [link2.m2_kg, link2.m3_kg_m, link2.m4_kg_m2]
    rng = np.random.default_rng(3)
    for _ in range(20):
        eta, eta_dot, tau = rng.uniform(-2.5, 1.0, 2), rng.uniform(-4, 4, 2), rng.uniform(-2, 2, 2)
        arm.eta, arm.eta_dot = eta.tolist(), eta_dot.tolist()
        # WHEN the base hovers level and still
        arm.step(tuple(tau), (0.0, 0.0, scenario.environment.gravity_m_s2), (0, 0, 0), (0, 0, 0))
        # THEN M_jj eta_ddot = tau - (C q_dot)_j - G_j, the joint rows with the base at rest
        q, q_dot = np.zeros(8), np.zeros(8)
        q[6:8], q_dot[6:8] = eta, eta_dot
        m = model.mass_matrix(q, theta)
        rhs = tau - (model.coriolis_matrix(q, q_dot, theta) @ q_dot)[6:8]
        expected = np.linalg.solve(m[6:8, 6:8], rhs - model.gravity(q, theta)[6:8])
        np.testing.assert_allclose(arm.eta_ddot, expected, rtol=1e-7, atol=1e-9)


def test_the_arm_starts_at_the_world_start_pose_with_servos_there(scenario):
    stand = ArmStand(scenario)
    assert stand.arm.eta == pytest.approx(list(scenario.world.start_joints_rad))
    for (config, servo), eta in zip(stand.joints, stand.arm.eta, strict=True):
        assert servo.get(ct.GOAL_POSITION) == units.rad_to_ticks(config.servo_angle_rad(eta))
        assert not servo.torque_enabled


def test_a_limp_arm_falls_and_hangs_straight_down_at_rest(scenario):
    # GIVEN torque off, link 1 forward: gravity swings it down
    stand = ArmStand(scenario)
    _run(stand, 0.2)
    (eta1, _), (rate1, _) = stand.arm.eta, stand.arm.eta_dot
    assert eta1 < -0.1 and rate1 < -0.5
    # GIVEN hanging straight down at rest: it stays there
    stand.arm.eta, stand.arm.eta_dot = [-0.5 * math.pi, 0.0], [0.0, 0.0]
    _run(stand, 0.5)
    np.testing.assert_allclose(stand.arm.eta, [-0.5 * math.pi, 0.0], atol=1e-9)


def test_servo_torque_holds_the_start_pose_against_gravity(scenario):
    stand = ArmStand(scenario)
    for _, servo in stand.joints:  # position mode is the factory default
        _put(servo, ct.TORQUE_ENABLE, 1)
    _run(stand, 1.0)
    start = list(scenario.world.start_joints_rad)
    # 17.8 N m/rad position loop against ~0.16 N m of gravity: under a degree of sag
    np.testing.assert_allclose(stand.arm.eta, start, atol=math.radians(1.0))
    assert abs(stand.torques_n_m[0]) > 0.1  # joint 1 carries the links' weight
    np.testing.assert_allclose(stand.arm.eta_dot, [0.0, 0.0], atol=1e-3)


def test_direction_and_zero_offset_map_joint_to_shaft(scenario):
    # GIVEN joint 1 mounted reversed, 0.3 rad off centre
    section = scenario.arm_bus
    joint1 = section.joints[0].model_copy(update={"direction": -1, "zero_offset_rad": 0.3})
    bus = section.model_copy(update={"joints": (joint1, *section.joints[1:])})
    stand = ArmStand(scenario.model_copy(update={"arm_bus": bus}))
    config, servo = stand.joints[0]
    _put(servo, ct.OPERATING_MODE, int(ct.OperatingMode.CURRENT))
    _put(servo, ct.TORQUE_ENABLE, 1)
    _put(servo, ct.GOAL_CURRENT, units.a_to_current_units(0.5))  # CCW at the shaft
    _run(stand, 0.05)
    # THEN the shaft reads 0.3 - eta (as of the step's start), and a CCW shaft torque is a
    # negative joint torque (less the gearbox friction at the shaft's rate -eta_dot)
    eta1, step = stand.arm.eta[0], abs(stand.arm.eta_dot[0]) * stand.dt_s
    assert units.ticks_to_rad(servo.get(ct.PRESENT_POSITION)) == pytest.approx(
        config.servo_angle_rad(eta1), abs=units.RAD_PER_TICK + step
    )
    shaft_n_m = servo.parameters.torque_constant_n_m_per_a * 0.5
    shaft_n_m -= servo.parameters.viscous_friction_n_m_s_per_rad * -stand.arm.eta_dot[0]
    assert stand.torques_n_m[0] == pytest.approx(-shaft_n_m, rel=0.05)
    assert eta1 < -0.05


def test_the_gripper_servo_closes_the_jaw_on_a_weightless_stand_in(scenario):
    """SIH carries no payload; the jaws still close on something, so the companion's
    gripper check (stopped short of closed, pushing) sees a grasp."""
    stand = ArmStand(scenario)
    gripper, servo = stand.gripper
    assert stand.jaw.angle_rad == gripper.open_position_rad and not stand.jaw.closed
    _put(servo, ct.TORQUE_ENABLE, 1)
    _put(servo, ct.GOAL_POSITION, units.rad_to_ticks(gripper.closed_position_rad))
    _run(stand, 0.5)
    assert stand.jaw.closed and stand.jaw.holding
    travel = gripper.closed_position_rad - gripper.open_position_rad
    on_object = gripper.open_position_rad + 0.8 * travel
    assert stand.jaw.angle_rad == pytest.approx(on_object, abs=0.02)
    assert abs(units.current_units_to_a(servo.get(ct.PRESENT_CURRENT))) > 1.0
    _put(servo, ct.GOAL_POSITION, units.rad_to_ticks(gripper.open_position_rad))
    _run(stand, 0.5)
    assert not stand.jaw.closed and not stand.jaw.holding
    assert stand.jaw.angle_rad == pytest.approx(gripper.open_position_rad, abs=0.02)


def test_the_servos_torque_constant_is_the_configs_times_the_plants_mismatch(scenario):
    plant = scenario.plant.model_copy(update={"servo_torque_constant_mismatch": 0.9})
    stand = ArmStand(scenario.model_copy(update={"plant": plant}))
    for config, servo in stand.joints:
        believed = config.torque_constant_n_m_per_a
        assert servo.parameters.torque_constant_n_m_per_a == pytest.approx(0.9 * believed)
    assert ArmStand(scenario).joints[0][1].parameters.torque_constant_n_m_per_a == (
        scenario.arm_bus.joints[0].torque_constant_n_m_per_a
    )


def test_a_scenario_without_servos_is_refused():
    with pytest.raises(ValueError, match=r"no \[arm_bus\]"):
        ArmStand(load_scenario(CONFIG.parent / "paper_sim.toml"))


@pytest.mark.slow
@pytest.mark.parametrize("speed", [1.0, 3.0])
def test_the_thread_steps_in_real_time(scenario, speed):
    stand = ArmStand(scenario, speed=speed)
    with stand:
        t0, steps0 = time.monotonic(), stand.steps
        time.sleep(0.5)
        elapsed, steps = time.monotonic() - t0, stand.steps - steps0
    stand.stop()  # idempotent
    expected = elapsed * speed / stand.dt_s
    assert steps == pytest.approx(expected, rel=0.15)
    assert stand.overruns == 0


@pytest.mark.slow
@pytest.mark.usefixtures("no_leaked_bus")
def test_our_driver_holds_the_arm_through_the_pty(scenario):
    joints, gripper = arm_bus_configs(scenario.arm_bus)

    async def session(url: str) -> tuple[dict, dict]:
        async with open_bus(url, joints, gripper=gripper) as bus:
            before = await bus.read_joint_states()
            await bus.set_operating_mode(OperatingMode.POSITION)
            await bus.enable_torque()
            await bus.write_joint_positions({"eta1": -0.3, "eta2": -1.2})
            await asyncio.sleep(1.0)
            return before, await bus.read_joint_states()

    with ArmStand(scenario) as stand:
        before, after = asyncio.run(
            session(f"dynamixel://{stand.device}?baud=1000000&timeout_margin_ms=50")
        )
    start = scenario.world.start_joints_rad
    assert before["eta1"].position_rad == pytest.approx(start[0], abs=0.05)
    assert before["eta2"].position_rad == pytest.approx(start[1], abs=0.05)
    assert after["eta1"].position_rad == pytest.approx(-0.3, abs=0.03)
    assert after["eta2"].position_rad == pytest.approx(-1.2, abs=0.03)

"""What goes wrong in a pickup, in the SITL's truth: a grasp that does not take, an object
that slips out mid-carry, a servo torque constant that is not the believed one; the
gripper servo tells a closed-on-object from a closed-on-nothing; the scenario keys and
``sitl run`` options that set them."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from test_bad_input_cli import changed, one_error, sitl
from test_sitl_world import GRIPPER, SCENARIO, _close_gripper, _position_mode

from arm_driver.dynamixel import control_table as ct
from arm_driver.dynamixel import units
from arm_driver.joint import JointConfig
from companion.config import ConfigError
from companion.mission.carry_check import CarryThresholds, gripper_holds
from sitl.physics import TruthPlant
from sitl.scenario import load_scenario
from sitl.servo import XM430Servo
from sitl.vehicle.options import RunOptions
from sitl.vehicle.runner import build_world, world_settings
from sitl.vehicle.world import World, WorldSettings

PICKUP = Path(__file__).resolve().parents[1] / "configs" / "sitl_pickup.toml"
OBJECT_STOP = GRIPPER.open_position_rad + 0.8 * (
    GRIPPER.closed_position_rad - GRIPPER.open_position_rad
)


def world_with_object(**faults) -> tuple[World, dict[int, XM430Servo]]:
    """The experiment arm standing, the object at its payload point, the gripper open."""
    joints = (-1.2, 0.3)
    configs = [JointConfig("eta1", 1, 1.78, 4.1), JointConfig("eta2", 2, 1.78, 4.1)]
    servos = {i: XM430Servo(i) for i in (1, 2, 3)}
    probe = World(
        TruthPlant.from_scenario(SCENARIO, "underactuated"),
        [(configs[0], servos[1]), (configs[1], servos[2])],
        (GRIPPER, servos[3]),
        WorldSettings(start_joints_rad=joints),
    )
    settings = WorldSettings(
        start_joints_rad=joints, payload_position_m=tuple(probe.payload_point_m()), **faults
    )
    servos = {i: XM430Servo(i) for i in (1, 2, 3)}
    world = World(
        TruthPlant.from_scenario(SCENARIO, "underactuated"),
        [(configs[0], servos[1]), (configs[1], servos[2])],
        (GRIPPER, servos[3]),
        settings,
    )
    for config, servo, angle in zip(configs, servos.values(), joints, strict=False):
        _position_mode(servo, config.servo_angle_rad(angle))
    _position_mode(servos[3], GRIPPER.open_position_rad)
    return world, servos


def gripper_reading(servo: XM430Servo) -> tuple[float, float]:
    """(shaft angle [rad], present current [A]) as the companion's bus reads them."""
    return (
        units.ticks_to_rad(servo.get(ct.PRESENT_POSITION)),
        units.current_units_to_a(servo.get(ct.PRESENT_CURRENT)),
    )


def companion_says_holding(servo: XM430Servo) -> bool:
    position, current = gripper_reading(servo)
    return gripper_holds(
        position,
        current,
        GRIPPER.open_position_rad,
        GRIPPER.closed_position_rad,
        CarryThresholds(),
    )


def test_jaws_stop_on_the_object_and_push_closed_on_nothing_they_reach_the_stop():
    world, servos = world_with_object()
    _close_gripper(world, servos)
    assert world.truth().payload_attached
    held_rad, held_a = gripper_reading(servos[3])
    assert held_rad == pytest.approx(OBJECT_STOP, abs=0.01) and abs(held_a) > 1.0
    assert companion_says_holding(servos[3])
    for _ in range(1500):  # 1.5 s more: pushing, but under the servo's overload current
        world.step(None)
    assert servos[3].torque_enabled and not servos[3].hardware_error
    missed, missed_servos = world_with_object(grasp_fails=True)
    _close_gripper(missed, missed_servos)
    assert missed.jaw.closed and not missed.truth().payload_attached
    empty_rad, empty_a = gripper_reading(missed_servos[3])
    assert empty_rad == pytest.approx(GRIPPER.closed_position_rad, abs=0.01)
    assert abs(empty_a) < 0.05
    assert not companion_says_holding(missed_servos[3])
    # The object stayed where it was.
    np.testing.assert_allclose(
        missed.truth().object_position_m, missed.settings.payload_position_m, atol=1e-12
    )


def test_object_slips_out_after_the_set_time_falls_and_the_jaws_close():
    world, servos = world_with_object(payload_slip_after_s=0.5)
    empty_m2 = world.truth().true_theta[0]
    _close_gripper(world, servos, steps=0)
    attached = []
    for _ in range(1000):
        world.step(None)
        attached.append((world.time_s, world.truth().payload_attached))
    held = [t for t, on in attached if on]
    assert held, "never grasped"
    assert held[-1] - held[0] == pytest.approx(0.5, abs=2e-3)  # held 0.5 s, then slipped
    assert world.slipped_at_s == pytest.approx(held[-1] + world.dt_s)
    truth = world.truth()
    assert not truth.payload_attached and truth.true_theta[0] == pytest.approx(empty_m2)
    rest_z = world.settings.payload_position_m[2]
    assert truth.object_position_m[2] <= rest_z + 1e-9
    assert gripper_reading(servos[3])[0] == pytest.approx(GRIPPER.closed_position_rad, abs=0.01)
    assert not companion_says_holding(servos[3])


def test_world_settings_reject_nonsense():
    with pytest.raises(ValueError, match="jaw_closure_on_object"):
        WorldSettings(jaw_closure_on_object=0.4)
    with pytest.raises(ValueError, match="payload_slip_after_s"):
        WorldSettings(payload_slip_after_s=-1.0)
    with pytest.raises(ValueError, match="payload_slip_after_s"):
        WorldSettings(payload_slip_after_s=math.inf)


def test_scenario_keys_reach_the_world_and_the_servo_truth(tmp_path):
    text = PICKUP.read_text()
    text = text.replace(
        "grasp_tolerance_m = 0.05 ",
        "grasp_tolerance_m = 0.05\ngrasp_fails = true\njaw_closure_on_object = 0.7\n"
        "[world.payload_slip]\nafter_grasp_s = 4.0\n#",
    )
    text = text.replace(
        "servo_torque_limit_n_m = 4.1 ",
        "servo_torque_limit_n_m = 4.1\nservo_torque_constant_mismatch = 1.1\n#",
    )
    path = tmp_path / "faults.toml"
    path.write_text(text)
    scenario = load_scenario(path)
    settings = world_settings(scenario)
    assert settings.grasp_fails and settings.payload_slip_after_s == 4.0
    assert settings.jaw_closure_on_object == 0.7
    world, _, joints, _ = build_world(scenario, RunOptions())
    believed = joints[0].torque_constant_n_m_per_a
    # The servo's truth is 10 % stronger per amp than the companion's config.
    servo = world._servos[0]
    assert servo.parameters.torque_constant_n_m_per_a == pytest.approx(1.1 * believed)
    assert world_settings(load_scenario(PICKUP)).payload_slip_after_s is None


@pytest.mark.parametrize(
    ("old", "new", "key"),
    [
        ("grasp_tolerance_m = 0.05 ", "jaw_closure_on_object = 1.2\ngrasp_tolerance_m = 0.05 #",
         "jaw_closure_on_object"),
        ("grasp_tolerance_m = 0.05 ", "grasp_fails = 1\ngrasp_tolerance_m = 0.05 #",
         "grasp_fails"),
        ("grasp_tolerance_m = 0.05 ",
         "grasp_tolerance_m = 0.05\n[world.payload_slip]\nafter_grasp_s = -2.0\n#",
         "world.payload_slip.after_grasp_s"),
        ("servo_torque_limit_n_m = 4.1 ",
         "servo_torque_constant_mismatch = 5.0\nservo_torque_limit_n_m = 4.1 #",
         "plant.servo_torque_constant_mismatch"),
    ],
)  # fmt: skip
def test_bad_fault_keys_are_one_line_naming_the_key(tmp_path, old, new, key):
    path = changed(tmp_path, PICKUP, old, new)
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        load_scenario(path)
    one_error(sitl("run", "--config", path, "--duration", "0.1"), key)


def test_sitl_run_fault_options_are_checked_before_anything_runs(tmp_path):
    one_error(
        sitl("run", "--config", PICKUP, "--payload-slip", "-1", "--duration", "0.1"),
        "--payload-slip",
    )
    one_error(
        sitl("run", "--config", PICKUP, "--payload-slip", "nan", "--duration", "0.1"),
        "--payload-slip",
    )
    no_object = changed(tmp_path, PICKUP, "payload_position_m = [1.5, 1.0, 0.05]", "")
    one_error(
        sitl("run", "--config", no_object, "--grasp-fails", "--duration", "0.1"),
        "--grasp-fails",
        "payload_position_m",
    )


def test_the_dynamixel_bus_reads_the_gripper_servo_position_and_current():
    import asyncio

    from arm_driver.bus import open_bus
    from sitl.servo import PtyServoBus

    joints = (JointConfig("eta1", 1, 1.78, 1.5), JointConfig("eta2", 2, 1.78, 1.5))
    world, servos = world_with_object()
    _close_gripper(world, servos)  # closed on the object, pushing
    expected_rad, expected_a = gripper_reading(servos[3])

    async def read():
        url = f"dynamixel://{sim.device}?timeout_margin_ms=50"
        async with open_bus(url, joints, gripper=GRIPPER) as bus:
            return await bus.read_gripper()

    with PtyServoBus(servos, step_servos=False) as sim:
        state = asyncio.run(asyncio.wait_for(read(), 10.0))
    assert state.position_rad == pytest.approx(expected_rad) == pytest.approx(OBJECT_STOP, abs=0.01)
    assert state.current_a == pytest.approx(expected_a) and abs(state.current_a) > 1.0

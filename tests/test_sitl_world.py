"""The SITL world: ground contact, servo coupling, gripper, payload grasp and release."""

import math

import numpy as np
import pytest

from arm_driver.dynamixel import control_table as ct
from arm_driver.dynamixel import units
from arm_driver.joint import GripperConfig, JointConfig
from sitl.physics import AttitudeSetpoint, PlantState, TruthPlant
from sitl.scenario import load_scenario
from sitl.servo import XM430Servo
from sitl.vehicle.world import IDEAL_SUPPLY, World, WorldSettings

SCENARIO = load_scenario("configs/experiment_arm.toml")
GRIPPER = GripperConfig(3, open_position_rad=0.8, closed_position_rad=-0.25)
GEAR_M = 0.25


def _position_mode(servo: XM430Servo, goal_rad: float) -> None:
    """What the companion's driver does over the bus, written straight into the model."""
    assert servo.write(ct.OPERATING_MODE.address, bytes([ct.OperatingMode.POSITION])).error == 0
    goal = int(units.rad_to_ticks(goal_rad)).to_bytes(4, "little", signed=True)
    assert servo.write(ct.GOAL_POSITION.address, goal).error == 0
    assert servo.write(ct.TORQUE_ENABLE.address, b"\x01").error == 0


def _world(joints=(-1.2, 0.3), direction=1, object_at=None, tolerance=0.05, jaw_point_m=None):
    plant = TruthPlant.from_scenario(SCENARIO, "underactuated")
    configs = [
        JointConfig("eta1", 1, 1.78, 4.1, direction=direction),
        JointConfig("eta2", 2, 1.78, 4.1, direction=direction),
    ]
    servos = {i: XM430Servo(i) for i in (1, 2, 3)}
    settings = WorldSettings(
        landing_gear_height_m=GEAR_M,
        payload_position_m=object_at,
        grasp_tolerance_m=tolerance,
        jaw_point_m=jaw_point_m,
        start_joints_rad=joints,
    )
    world = World(
        plant, [(configs[0], servos[1]), (configs[1], servos[2])], (GRIPPER, servos[3]), settings
    )
    for config, servo, angle in zip(configs, servos.values(), joints, strict=False):
        _position_mode(servo, config.servo_angle_rad(angle))
    _position_mode(servos[3], GRIPPER.open_position_rad)
    return world, servos


def test_disarmed_vehicle_stands_still_and_accelerometer_reads_plus_g():
    world, _ = _world()
    for _ in range(500):
        state = world.step(None)
    assert world.on_ground
    assert state.q[2] == pytest.approx(GEAR_M)
    np.testing.assert_allclose(state.q_dot[0:6], 0.0, atol=1e-12)
    np.testing.assert_allclose(
        world.specific_force_flu_m_s2(), [0.0, 0.0, SCENARIO.environment.gravity_m_s2], atol=1e-9
    )
    # The servos hold the arm where it started.
    np.testing.assert_allclose(state.q[6:8], [-1.2, 0.3], atol=0.03)


def test_thrust_above_hover_lifts_off_and_below_hover_does_not():
    world, _ = _world()
    for _ in range(300):
        world.step(AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, 0.15))
    assert world.on_ground
    for _ in range(800):
        state = world.step(AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, 0.7))
    assert not world.on_ground
    assert state.q[2] > GEAR_M + 0.2
    assert world.specific_force_flu_m_s2()[2] > SCENARIO.environment.gravity_m_s2
    assert world.battery == IDEAL_SUPPLY  # no plant.battery in this scenario


def test_servo_direction_reverses_the_joint_torque():
    torques = []
    for direction in (1, -1):
        world, servos = _world(joints=(0.0, 0.0), direction=direction)
        # Drive joint 1's servo to a shaft angle of +0.3 rad.
        goal = int(units.rad_to_ticks(0.3)).to_bytes(4, "little", signed=True)
        servos[1].write(ct.GOAL_POSITION.address, goal)
        for _ in range(20):
            world.step(None)
        torques.append(world.truth().joint_torques_n_m[0])
    assert torques[0] * torques[1] < 0.0


def test_a_standing_arm_swings_down_under_gravity_and_the_rotors_do_not_pump_it():
    """On the ground the arm moves as on a stand. Before, the ground pinned the base after
    a free step: a limp arm floated (it fell with the base) and the rotors' torque on the
    held base spun it (5 rad/s on the ground under PX4 after a landing)."""
    world, servos = _world(joints=(0.0, -0.5 * math.pi))
    for i in (1, 2):
        assert servos[i].write(ct.TORQUE_ENABLE.address, b"\x00").error == 0
    for _ in range(300):
        state = world.step(None)
    assert world.on_ground and state.q[6] < -0.3  # link 1 falls
    pitch_up = AttitudeSetpoint.from_euler(0.0, 0.3, 0.0, 0.15)  # a pitch torque, no lift
    for _ in range(8000):
        state = world.step(pitch_up)
    assert world.on_ground
    assert abs(world.plant.actuators.torque_normalized[1]) > 0.05  # pitch torque asked
    np.testing.assert_allclose(state.q[6:8], [-0.5 * math.pi, 0.0], atol=0.05)
    np.testing.assert_allclose(state.q_dot[6:8], 0.0, atol=0.05)


def _close_gripper(world, servos, steps=400):
    goal = int(units.rad_to_ticks(GRIPPER.closed_position_rad)).to_bytes(4, "little", signed=True)
    servos[3].write(ct.GOAL_POSITION.address, goal)
    for _ in range(steps):
        world.step(None)


def _open_gripper(world, servos, steps=400):
    goal = int(units.rad_to_ticks(GRIPPER.open_position_rad)).to_bytes(4, "little", signed=True)
    servos[3].write(ct.GOAL_POSITION.address, goal)
    for _ in range(steps):
        world.step(None)


def test_gripper_grasps_an_object_within_tolerance_and_releases_it():
    probe, _ = _world()
    point = probe.jaw_point_m()
    world, servos = _world(object_at=tuple(np.add(point, [0.02, 0.0, 0.0])))
    empty = world.truth().true_theta
    _close_gripper(world, servos)
    truth = world.truth()
    assert world.jaw.closed
    assert truth.payload_attached
    # On the ground the object's weight stays on the ground: the jaws have not lifted it.
    assert truth.true_theta[0] == pytest.approx(empty[0], abs=0.02 * SCENARIO.payload.mass_kg)
    np.testing.assert_allclose(truth.object_position_m, world.jaw_point_m())
    _open_gripper(world, servos)
    truth = world.truth()
    assert not truth.payload_attached
    assert truth.true_theta[0] == pytest.approx(empty[0])
    assert truth.object_position_m[2] <= point[2] + 1e-9


def test_the_jaws_grasp_where_they_are_and_the_mass_sits_at_the_payloads_own_point():
    """The jaws (2 cm inside link 2's tip) take the object; its centre of mass lies at the
    payload's point along link 2 (4 cm short of the jaws here), which the grasp does not
    need to be over the object."""
    probe, _ = _world()
    jaws, com = probe.jaw_point_m(), probe.payload_point_m()
    jaw_at = SCENARIO.arm.link2.length_m - 0.02
    assert math.dist(jaws, com) == pytest.approx(jaw_at - SCENARIO.payload.position_m)
    assert math.dist(jaws, com) > 0.03
    world, servos = _world(object_at=tuple(jaws))
    _close_gripper(world, servos)
    assert world.truth().payload_attached
    np.testing.assert_allclose(world.truth().object_position_m, world.jaw_point_m())
    # Where the jaws are is the truth's own setting: set at the payload's point, the jaws
    # stay 4 cm from an object resting at the default jaw point, beyond a 3 cm tolerance.
    far, servos = _world(
        object_at=tuple(jaws), tolerance=0.03, jaw_point_m=SCENARIO.payload.position_m
    )
    np.testing.assert_allclose(far.jaw_point_m(), com)
    _close_gripper(far, servos)
    assert far.jaw.closed and not far.truth().payload_attached


def test_gripper_closing_far_from_the_object_grasps_nothing():
    probe, _ = _world()
    point = probe.jaw_point_m()
    world, servos = _world(object_at=tuple(np.add(point, [0.2, 0.0, 0.0])))
    _close_gripper(world, servos)
    assert world.jaw.closed
    assert not world.truth().payload_attached
    np.testing.assert_allclose(world.truth().object_position_m, np.add(point, [0.2, 0.0, 0.0]))


def test_settings_reject_nonsense():
    with pytest.raises(ValueError, match="landing_gear"):
        WorldSettings(landing_gear_height_m=0.0)
    with pytest.raises(ValueError, match="finite"):
        WorldSettings(start_yaw_rad=math.nan)
    with pytest.raises(ValueError, match="jaw_point_m"):
        WorldSettings(jaw_point_m=-0.1)


def test_jsbsim_plant_stands_on_its_own_gear_in_the_world():
    from sitl.physics.jsbsim import GearGeometry, JsbsimPlant

    plant = JsbsimPlant.from_scenario(SCENARIO, "underactuated", gear=GearGeometry(height_m=GEAR_M))
    servos = {i: XM430Servo(i) for i in (1, 2, 3)}
    configs = [JointConfig("eta1", 1, 1.78, 4.1), JointConfig("eta2", 2, 1.78, 4.1)]
    world = World(
        plant,
        [(configs[0], servos[1]), (configs[1], servos[2])],
        (GRIPPER, servos[3]),
        WorldSettings(landing_gear_height_m=GEAR_M, start_joints_rad=(-1.2, 0.3)),
    )
    for _ in range(500):
        state = world.step(None)
    assert world.on_ground
    assert state.q[2] == pytest.approx(GEAR_M, abs=0.03)
    for _ in range(800):
        state = world.step(AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, 0.7))
    assert not world.on_ground and state.q[2] > GEAR_M + 0.2


def test_advancing_builds_no_truth_state_until_one_is_read_and_flies_the_same(monkeypatch):
    built = []
    from_lists = PlantState.from_lists

    def counted(*args):
        built.append(args[0])
        return from_lists(*args)

    monkeypatch.setattr(PlantState, "from_lists", counted)
    stepped, _ = _world(object_at=(0.3, 0.0, 0.05))
    advanced, _ = _world(object_at=(0.3, 0.0, 0.05))
    climb = AttitudeSetpoint.from_euler(0.0, 0.02, 0.0, 0.7)
    setpoints = [None] * 400 + [climb] * 400 + [None] * 2500  # stand, climb, fall, land
    flew = False
    for k, setpoint in enumerate(setpoints):
        state = stepped.step(setpoint)
        del built[:]
        advanced.advance(setpoint)
        assert built == []  # on the ground and in the air: nothing read, nothing built
        if k % 97 == 0 or k == len(setpoints) - 1:
            read = advanced.state
            for field in ("q", "q_dot", "q_ddot", "quaternion_wxyz", "rotation_world_body"):
                assert getattr(read, field).tobytes() == getattr(state, field).tobytes()
            assert read.time_s == state.time_s == advanced.time_s
            assert advanced.on_ground == stepped.on_ground
            q, q_dot = advanced.plant.coordinates
            assert list(q) == read.q.tolist() and list(q_dot) == read.q_dot.tolist()
        flew = flew or not advanced.on_ground
    assert flew and advanced.on_ground

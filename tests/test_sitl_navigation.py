"""sitl.vehicle.navigation: the EKF2-like estimate on PX4's 125 Hz output grid, per aiding mode."""

import numpy as np
import pytest

from arm_driver.joint import GripperConfig, JointConfig
from sitl.physics import AttitudeSetpoint, TruthPlant
from sitl.scenario import load_scenario
from sitl.servo import XM430Servo
from sitl.vehicle.navigation import ERROR_MODELS, Navigation
from sitl.vehicle.world import World, WorldSettings

SCENARIO = load_scenario("configs/sitl_pickup.toml")


def _world(start=(0.3, -0.2, 0.0)) -> World:
    plant = TruthPlant.from_scenario(SCENARIO, "underactuated")
    joints = [JointConfig("eta1", 1, 1.78, 4.1), JointConfig("eta2", 2, 1.78, 4.1)]
    servos = {i: XM430Servo(i) for i in (1, 2, 3)}
    gripper = GripperConfig(3, open_position_rad=0.8, closed_position_rad=-0.25)
    settings = WorldSettings(landing_gear_height_m=0.25, start_position_m=start)
    return World(
        plant, [(joints[0], servos[1]), (joints[1], servos[2])], (gripper, servos[3]), settings
    )


def _run(world, nav, seconds, thrust=0.0):
    """Step the world, measuring every step; returns the distinct estimates."""
    estimates, last = [], None
    setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, thrust)
    for _ in range(round(seconds / world.dt_s)):
        m = nav.measure(world)
        if m is not last:
            estimates.append((m, world.state))
            last = m
        world.step(setpoint)
    return estimates


def test_estimates_come_every_8_ms_stamped_with_the_imu_sample_time():
    world = _world()
    nav = Navigation(SCENARIO, np.random.default_rng(0), mode="mocap")
    estimates = _run(world, nav, 0.2)
    stamps = [m.estimate_time_us for m, _ in estimates]
    assert stamps[:3] == [0, 8000, 16000]
    assert set(np.diff(stamps)) == {8000}
    assert all(s % 4000 == 0 for s in stamps)  # on the 250 Hz IMU grid
    assert nav.output_period_s == pytest.approx(0.008)


@pytest.mark.parametrize(("mode", "horizontal_m", "vertical_m"), [("mocap", 0.02, 0.02),
                                                                  ("gps", 1.0, 1.0)])  # fmt: skip
def test_errors_are_the_size_of_the_mode(mode, horizontal_m, vertical_m):
    errors = []
    for seed in range(20):
        world = _world(start=(0.0, 0.0, 0.0))
        nav = Navigation(SCENARIO, np.random.default_rng(seed), mode=mode)
        m, state = _run(world, nav, 0.05)[-1]
        errors.append(m.position_enu_m - (state.q[0:3] - nav.local_origin_enu_m))
    errors = np.array(errors)
    model = ERROR_MODELS[mode]
    assert np.max(np.abs(errors[:, :2])) < horizontal_m
    assert np.max(np.abs(errors[:, 2])) < vertical_m
    # boot offsets of the size measured on PX4 (mocap: mm, GPS: 0.2-0.3 m)
    assert np.std(errors[:, 0]) == pytest.approx(model.boot_std_m, rel=0.6)
    assert m.estimator == model.report


def test_gps_frame_starts_at_the_vehicle_mocap_frame_is_the_worlds():
    world = _world(start=(0.3, -0.2, 0.0))
    gps = Navigation(SCENARIO, np.random.default_rng(0), mode="gps", noise=False)
    mocap = Navigation(SCENARIO, np.random.default_rng(0), mode="mocap", noise=False)
    at_rest_gps, at_rest_mocap = gps.measure(world), mocap.measure(world)
    np.testing.assert_allclose(at_rest_gps.position_enu_m, 0.0, atol=1e-12)
    np.testing.assert_allclose(at_rest_mocap.position_enu_m, [0.3, -0.2, 0.25], atol=1e-12)


def test_exact_estimate_is_the_truth_and_velocity_is_smooth_with_noise():
    world = _world()
    exact = Navigation(SCENARIO, np.random.default_rng(1), mode="gps", noise=False)
    m, state = _run(world, exact, 0.1)[-1]
    np.testing.assert_allclose(m.velocity_enu_m_s, state.q_dot[0:3], atol=1e-12)
    world = _world()
    noisy = Navigation(SCENARIO, np.random.default_rng(1), mode="gps")
    velocities = np.array([m.velocity_enu_m_s for m, _ in _run(world, noisy, 2.0)])
    # an EKF's velocity: millimetres per second from one 8 ms estimate to the next
    steps = np.abs(np.diff(velocities, axis=0))
    assert np.std(steps) < 0.005 and np.max(steps) < 0.02

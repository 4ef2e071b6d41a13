"""PX4's tilt loop inverted (companion.control.attitude_feedforward), judged by the SITL's PX4 loop.

The belief the offset rests on (PX4's attitude P, rate PI and allocation hold a torque with
a predictable attitude error) is checked against the SITL's own implementation of PX4's
loop and mixer (sitl.physics.attitude_control, sitl.physics.rotors: PX4's
ControlAllocationPseudoInverse normalization and the THR_MDL_FAC curve), not against the
companion's model of it. The offline closed loop with it is in test_simulation.py; the
compiled step's copy in test_compiled_step.py.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from companion.config import ConfigError, parse_config
from companion.control.attitude_feedforward import AttitudeLoopInverse
from sitl.physics.attitude_control import AttitudeLoopParams, AttitudeSetpoint, Px4AttitudeLoop
from sitl.physics.rotors import (
    RotorGeometry,
    SequentialDesaturationMixer,
    thrust_curve,
)
from sitl.scenario import load_scenario

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
WITH_FEEDFORWARD = ("paper_sim_flight.toml", "sitl_pickup.toml")


def pitch_against_a_disturbance(offsets: bool, duration_s: float = 30.0) -> np.ndarray:
    """Pitch [rad] of a body (pitch inertia 0.05 kg m^2) held level by the SITL's PX4 loop
    and rotors against a disturbance torque 0.3 + 0.7 sin(0.2 pi t) N m (an arm swinging a
    payload at 0.1 Hz), with or without the companion's offset for that torque, at 1 kHz."""
    scenario = load_scenario(CONFIGS / "paper_sim_flight.toml")
    rotors = scenario.vehicle.rotors
    geometry = RotorGeometry.hexa_x(rotors.arm_length_m, rotors.yaw_moment_per_thrust_m)
    mixer = SequentialDesaturationMixer(geometry, rotors.max_thrust_per_rotor_n)
    dt = 1e-3
    px4 = Px4AttitudeLoop.from_params(
        AttitudeLoopParams.from_config(scenario.plant.attitude_control, rotors.thr_mdl_fac),
        mixer,
        dt,
    )
    section = scenario.beliefs.controller.attitude_feedforward
    assert section is not None
    inverse = AttitudeLoopInverse.from_config(section)
    pitch_row = geometry.wrench_matrix()[1]
    inertia, pitch, rate = 0.05, 0.0, 0.0
    out = []
    for i in range(round(duration_s / dt)):
        t = i * dt
        disturbance = 0.3 + 0.7 * math.sin(0.2 * math.pi * t)
        command = 0.0
        if offsets:
            command = float(inverse.offset(dt, np.array([0.0, disturbance]))[1])
        q = (math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0)
        setpoint = AttitudeSetpoint.from_euler(0.0, command, 0.0, 0.5)
        motors = px4.update(q, (0.0, rate, 0.0), setpoint).motor_commands
        thrusts = rotors.max_thrust_per_rotor_n * thrust_curve(motors, rotors.thr_mdl_fac)
        torque = float(pitch_row @ thrusts)
        rate += dt * (torque - disturbance) / inertia
        pitch += dt * rate
        out.append(pitch)
    return np.array(out)


def test_the_offset_makes_px4s_loop_hold_the_attitude_against_the_torque():
    """GIVEN PX4's loop (the SITL's) holding level against a slow disturbance torque
    WHEN the companion adds the offset for that torque to the commanded pitch
    THEN the held pitch error falls from 0.16 rad to 0.005 rad (measured)."""
    without = pitch_against_a_disturbance(offsets=False)
    with_offset = pitch_against_a_disturbance(offsets=True)
    settled = slice(5000, None)
    assert np.max(np.abs(without[settled])) > 0.1
    assert np.max(np.abs(with_offset[settled])) < 0.01


@pytest.mark.parametrize("name", WITH_FEEDFORWARD)
def test_configured_loop_is_the_simulated_vehicles(name):
    """The configs model the loop and allocation their SITL vehicle flies with."""
    scenario = load_scenario(CONFIGS / name)
    section = scenario.beliefs.controller.attitude_feedforward
    assert section is not None
    plant = scenario.plant.attitude_control
    assert section.attitude_p == tuple(plant.attitude_p[:2])
    assert section.rate_p == tuple(plant.rate_p[:2])
    assert section.rate_i == tuple(plant.rate_i[:2])
    assert section.rate_integrator_limit == tuple(plant.rate_integrator_limit[:2])
    rotors = scenario.vehicle.rotors
    mixer = SequentialDesaturationMixer(
        RotorGeometry.hexa_x(rotors.arm_length_m, rotors.yaw_moment_per_thrust_m),
        rotors.max_thrust_per_rotor_n,
    )
    np.testing.assert_allclose(
        section.torque_per_normalized_n_m, mixer.torque_per_normalized_n_m[:2], rtol=2e-3
    )


def inverse(**changes) -> AttitudeLoopInverse:
    values = {
        "attitude_p": (4.0, 4.0),
        "rate_p": (0.15, 0.15),
        "rate_i": (0.2, 0.2),
        "integrator_limit": (0.3, 0.3),
        "torque_per_normalized_n_m": (3.16, 3.16),
        "max_offset_rad": 0.3,
        "torque_filter_s": 1e-6,
    }
    values.update(changes)
    return AttitudeLoopInverse(**values)


def test_a_constant_torque_is_left_to_px4s_integrator():
    """A step of torque first gets the P-only offset d / (T k_p k_a), then fades with the
    integrator's time constant k_p / k_i (0.75 s): PX4's own integrator holds a constant
    torque without an attitude error."""
    loop = inverse()
    dt = 1e-3
    first = loop.offset(dt, np.array([0.5, -0.5]))
    np.testing.assert_allclose(
        first, [0.5 / (3.16 * 0.15 * 4.0), -0.5 / (3.16 * 0.15 * 4.0)], rtol=2e-3
    )
    for _ in range(round(0.75 / dt)):
        e = loop.offset(dt, np.array([0.5, -0.5]))
    np.testing.assert_allclose(e, first * math.exp(-1.0), rtol=0.01)
    for _ in range(round(5.0 / dt)):
        e = loop.offset(dt, np.array([0.5, -0.5]))
    assert np.all(np.abs(e) < 1e-3 * np.abs(first))
    np.testing.assert_allclose(loop.integral, [0.5 / 3.16, -0.5 / 3.16], rtol=1e-3)
    loop.reset()
    assert np.array_equal(loop.integral, [0.0, 0.0])
    assert np.array_equal(loop.torque_n_m, [0.0, 0.0])


def test_the_torque_is_low_passed_with_its_time_constant():
    loop = inverse(torque_filter_s=0.05, rate_i=(0.0, 0.0))
    dt = 1e-3
    for _ in range(50):
        e = loop.offset(dt, np.array([0.2, 0.4]))
    step = 1.0 - math.exp(-1.0)
    np.testing.assert_allclose(loop.torque_n_m, [0.2 * step, 0.4 * step], rtol=0.01)
    np.testing.assert_allclose(e, loop.torque_n_m / (3.16 * 0.15 * 4.0))


def test_offset_and_integrator_copy_are_limited_as_px4s():
    loop = inverse(integrator_limit=(0.1, 0.1))
    e = loop.offset(1e-3, np.array([100.0, -100.0]))
    np.testing.assert_array_equal(e, [0.3, -0.3])
    pitch_only = inverse(max_offset_rad=(0.0, 0.2))
    e = pitch_only.offset(1e-3, np.array([100.0, -100.0]))
    np.testing.assert_array_equal(e, [0.0, -0.2])
    assert pitch_only.integral[0] == 0.0  # no offset sent: PX4's integrator is not driven
    for _ in range(2000):
        loop.offset(1e-3, np.array([100.0, -100.0]))
    np.testing.assert_array_equal(loop.integral, [0.1, -0.1])


@pytest.mark.parametrize(
    "changes",
    [
        {"attitude_p": (0.0, 4.0)},
        {"rate_p": (0.15,)},
        {"rate_i": (-0.1, 0.2)},
        {"torque_per_normalized_n_m": (math.nan, 3.0)},
        {"max_offset_rad": -0.1},
        {"max_offset_rad": (0.3, 0.3, 0.3)},
        {"torque_filter_s": 0.0},
    ],
)
def test_bad_loop_values_are_refused(changes):
    with pytest.raises(ValueError):
        inverse(**changes)


def test_config_section_is_validated_with_a_clear_error():
    data = tomllib.loads((CONFIGS / "sitl_pickup.toml").read_text())
    data["controller"]["attitude_feedforward"]["rate_p"] = [0.15]
    with pytest.raises(ConfigError, match=r"attitude_feedforward\.rate_p"):
        parse_config(data)
    data["controller"]["attitude_feedforward"]["rate_p"] = [0.15, 0.15]
    data["controller"]["attitude_feedforward"]["max_offset_rad"] = 1.0
    with pytest.raises(ConfigError, match="max_offset_rad"):
        parse_config(data)
    data["controller"]["attitude_feedforward"]["max_offset_rad"] = [0.0, 0.6]
    with pytest.raises(ConfigError, match="max_offset_rad"):
        parse_config(data)
    data["controller"]["attitude_feedforward"]["max_offset_rad"] = 0.2  # one number: both
    section = parse_config(data).controller.attitude_feedforward
    assert section is not None and section.max_offset_rad == (0.2, 0.2)

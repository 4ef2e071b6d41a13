"""Cross-validation: the JSBSim backend against the Pinocchio plant, wind off.

Same scenario (configs/paper_sim_flight.toml, payload grasped), same inputs through the
same PX4-like loop and rotors; the backends differ in the rigid-body integration (JSBSim's
EOM and multistep integrators against Pinocchio's ABA with semi-implicit Euler), in the
arm coupling (one-step lag on the JSBSim side), and in where the drag acts (CG velocity
in JSBSim, vehicle CoM velocity in Pinocchio). Tolerances are about three times the
differences measured at 1 kHz (given in each docstring).
"""

import math
from pathlib import Path

import numpy as np
import pytest

from sitl.physics import AttitudeSetpoint, make_plant
from sitl.scenario import Scenario, load_scenario

CONFIGS = Path(__file__).parent.parent / "configs"
FLIGHT = load_scenario(CONFIGS / "paper_sim_flight.toml")


def command(plant, tilt_rad: float = 0.0, factor: float = 1.0) -> float:
    """The believed relative hover thrust (companion's thrust model), times ``factor``."""
    rotors = FLIGHT.vehicle.rotors
    weight = plant.total_mass_kg * FLIGHT.environment.gravity_m_s2 / math.cos(tilt_rad)
    return factor * weight / (6 * rotors.max_thrust_per_rotor_n)


def fly(cfg: Scenario, physics: str, inputs, duration_s: float) -> np.ndarray:
    """q at every step of a run driven by ``inputs(plant, t) -> (setpoint, torques)``."""
    plant = make_plant(cfg, physics, "underactuated", payload_attached=True)
    steps = round(duration_s * plant.rate_hz)
    out = np.empty((steps, 8))
    for i in range(steps):
        setpoint, torques = inputs(plant, i * plant.dt_s)
        out[i] = plant.step(setpoint, torques).q
    return out


def both(cfg: Scenario, inputs, duration_s: float) -> tuple[np.ndarray, np.ndarray]:
    return fly(cfg, "pinocchio", inputs, duration_s), fly(cfg, "jsbsim", inputs, duration_s)


def arm_swing(plant, t: float):
    """Level hover while the servos swing the arm (PD on a 0.5 Hz sinusoid, +-0.4 rad and
    +-0.3 rad): the arm's reaction rocks the vehicle in pitch and pushes it along x. The
    thrust is the hover thrust over the cosine of the pitch (PX4's linearized motors give no
    extra thrust when the mixer rocks the vehicle; without it the vehicle sinks 0.6 m)."""
    state = plant.state
    ref = np.array([-math.pi / 2 + 0.4 * math.sin(math.pi * t), 0.3 * math.sin(math.pi * t)])
    torques = 4.0 * (ref - state.q[6:8]) - 0.4 * state.q_dot[6:8]
    thrust = command(plant, tilt_rad=float(state.q[4]))
    return AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, thrust), torques


def test_hover_thrust_agrees() -> None:
    """At the believed hover thrust both plants hold still with the rotors carrying the
    same weight (JSBSim's gravity, masses and unit conversions against ours)."""
    for physics in ("pinocchio", "jsbsim"):
        plant = make_plant(FLIGHT, physics, payload_attached=True)
        setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, command(plant))
        for _ in range(1000):
            state = plant.step(setpoint, [0.0, 0.0])
        weight = plant.total_mass_kg * FLIGHT.environment.gravity_m_s2
        assert plant.rotor_thrusts_n.sum() == pytest.approx(weight, rel=1e-9)
        np.testing.assert_allclose(state.q, FLIGHT.simulation.initial_q, atol=1e-4)


def test_vertical_step_agrees() -> None:
    """10 % above hover thrust for 2 s: the climbs agree within 0.5 mm over 1.8 m
    (measured 0.05 mm)."""

    def inputs(plant, t):
        return AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, command(plant, factor=1.1)), (0, 0)

    pin_q, jsb_q = both(FLIGHT, inputs, 2.0)
    assert pin_q[-1, 2] - pin_q[0, 2] > 1.5
    assert np.abs(pin_q[:, 2] - jsb_q[:, 2]).max() < 5e-4
    assert np.abs(pin_q[:, 3:6] - jsb_q[:, 3:6]).max() < 1e-6


def test_pitch_step_agrees() -> None:
    """A 0.1 rad pitch step held for 2 s (vehicle accelerates along x, the free arm swings
    back): pitch within 3 mrad (measured 0.6), x within 1 cm over 1.5 m (3.0 mm), joints
    within 15 mrad (4.3)."""

    def inputs(plant, t):
        return AttitudeSetpoint.from_euler(0.0, 0.1, 0.0, command(plant, 0.1)), (0.0, 0.0)

    pin_q, jsb_q = both(FLIGHT, inputs, 2.0)
    assert pin_q[-1, 0] - pin_q[0, 0] > 1.0
    diff = np.abs(pin_q - jsb_q).max(axis=0)
    assert diff[4] < 3e-3
    assert diff[0] < 1e-2 and diff[2] < 2e-3
    assert diff[6] < 15e-3 and diff[7] < 15e-3


def test_arm_swing_agrees() -> None:
    """The servo-driven arm swing for 4 s: joints within 2 mrad (measured 0.5), pitch within
    3 mrad of its 0.33 rad swing (1.4), position within 1 cm (3 mm)."""
    pin_q, jsb_q = both(FLIGHT, arm_swing, 4.0)
    assert np.ptp(pin_q[:, 4]) > 0.2  # the arm really rocks the vehicle
    diff = np.abs(pin_q - jsb_q).max(axis=0)
    assert diff[6] < 2e-3 and diff[7] < 2e-3
    assert diff[4] < 3e-3
    assert diff[0] < 1e-2 and diff[2] < 1e-2


def test_arm_coupling_converges_with_the_step() -> None:
    """The lagged coupling is consistent: without drag (whose point of action differs by
    design), the arm-swing difference shrinks at least 2x from 1 kHz to 3 kHz (measured
    3.0x in x, z, pitch and joints: first order). What remains at 1 kHz is discretization,
    not a model error, and the coupled loop is stable at both rates."""
    diffs = []
    for rate in (1000.0, 3000.0):
        plant = FLIGHT.plant.model_copy(update={"rate_hz": rate, "linear_drag_n_s_m": (0, 0, 0)})
        cfg = FLIGHT.model_copy(update={"plant": plant})
        pin_q, jsb_q = both(cfg, arm_swing, 1.5)
        assert np.all(np.isfinite(jsb_q))
        diffs.append(np.abs(pin_q - jsb_q).max(axis=0))
    coarse, fine = diffs
    for row in (4, 6, 7):
        assert fine[row] < 0.5 * coarse[row]

"""sitl.physics: the underactuated plant (rotors, PX4-like loop, servos) end to end."""

import math
from pathlib import Path

import numpy as np
import pytest

from sitl.physics import AttitudeSetpoint, TruthPlant
from sitl.physics.attitude_control import AttitudeLoopParams
from sitl.physics.rotors import inverse_thrust_curve, thrust_curve
from sitl.scenario import Scenario, load_scenario

CONFIGS = Path(__file__).parent.parent / "configs"
PAPER = load_scenario(CONFIGS / "paper_sim.toml")


def with_plant(cfg: Scenario, **changes) -> Scenario:
    return cfg.model_copy(update={"plant": cfg.plant.model_copy(update=changes)})


def believed_hover_thrust(cfg: Scenario, mass_kg: float, tilt_rad: float = 0.0) -> float:
    """The relative thrust the companion would send: weight over its believed maximum
    thrust (no mismatch); PX4 linearizes it with THR_MDL_FAC."""
    rotors = cfg.vehicle.rotors
    return (
        mass_kg
        * cfg.environment.gravity_m_s2
        / math.cos(tilt_rad)
        / (6 * rotors.max_thrust_per_rotor_n)
    )


def test_hover_at_the_relative_hover_thrust_holds_still() -> None:
    """GIVEN the paper vehicle with payload, arm down WHEN commanded level at weight over
    maximum thrust THEN it stays put, the rotors carry exactly its weight and the motors
    run at the THR_MDL_FAC inverse of that relative thrust."""
    plant = TruthPlant.from_scenario(PAPER, "underactuated", payload_attached=True)
    hover = believed_hover_thrust(PAPER, plant.total_mass_kg)
    u_hover = float(inverse_thrust_curve(hover, PAPER.vehicle.rotors.thr_mdl_fac))
    assert 0.4 < u_hover < 0.55  # the nominal vehicle hovers near half throttle
    setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, hover)
    for _ in range(2000):
        state = plant.step(setpoint, [0.0, 0.0])
    np.testing.assert_allclose(state.q, PAPER.simulation.initial_q, atol=1e-9)
    np.testing.assert_allclose(state.q_dot, 0.0, atol=1e-9)
    weight = plant.total_mass_kg * PAPER.environment.gravity_m_s2
    assert plant.rotor_thrusts_n.sum() == pytest.approx(weight, rel=1e-9)
    np.testing.assert_allclose(plant.actuators.motor_commands, u_hover, atol=1e-9)


def test_thrust_mismatch_makes_the_believed_hover_thrust_sink() -> None:
    """Truth rotors 10 % weaker than believed: at the believed hover thrust the vehicle
    accelerates down at 0.1 g once the rotor lag has settled."""
    cfg = with_plant(PAPER, thrust_mismatch=0.9, linear_drag_n_s_m=(0.0, 0.0, 0.0))
    plant = TruthPlant.from_scenario(cfg, "underactuated", payload_attached=True)
    hover = believed_hover_thrust(cfg, plant.total_mass_kg)
    setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, hover)
    for _ in range(500):
        state = plant.step(setpoint, [0.0, 0.0])
    g = cfg.environment.gravity_m_s2
    assert state.q_ddot[2] == pytest.approx(-0.1 * g, rel=1e-3)
    assert plant.rotor_thrusts_n.sum() == pytest.approx(0.9 * plant.total_mass_kg * g, rel=1e-3)


def test_steady_wind_acts_through_the_drag_on_the_velocity_relative_to_the_air() -> None:
    """GIVEN a steady wind w WHEN the vehicle flies at v THEN it moves exactly as in calm
    air at v - w (the drag -D (v - w) is all the wind does): at rest in the wind it is
    pushed downwind, and carried along at the wind's own velocity it feels no drag."""
    wind = (2.0, -1.0, 0.5)
    windy_cfg = with_plant(PAPER, wind_m_s=wind)
    q0 = PAPER.simulation.initial_q
    hover = believed_hover_thrust(PAPER, TruthPlant.from_scenario(PAPER).total_mass_kg)
    setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, hover)

    def first_step(cfg: Scenario, velocity: tuple[float, float, float], **kw) -> np.ndarray:
        plant = TruthPlant.from_scenario(cfg, "underactuated", **kw)
        plant.reset(q0, [*velocity, 0.0, 0.0, 0.0, 0.0, 0.0])
        return plant.step(setpoint, [0.0, 0.0]).q_ddot

    at_rest = first_step(windy_cfg, (0.0, 0.0, 0.0))
    calm_against = first_step(PAPER, (-2.0, 1.0, -0.5))
    np.testing.assert_allclose(at_rest, calm_against, rtol=0, atol=1e-12)
    assert at_rest[0] > 0.0 and at_rest[1] < 0.0  # pushed downwind
    carried = first_step(windy_cfg, wind)
    np.testing.assert_allclose(carried, first_step(PAPER, (0.0, 0.0, 0.0)), rtol=0, atol=1e-12)
    replaced = first_step(windy_cfg, (0.0, 0.0, 0.0), wind_m_s=(0.0, 0.0, 0.0))
    np.testing.assert_allclose(replaced, first_step(PAPER, (0.0, 0.0, 0.0)), rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    ("payload", "rise_s", "settle_s", "overshoot_deg"),
    [(False, 0.45, 0.5, 1.5), (True, 0.5, 1.9, 3.0)],
    ids=["empty", "payload"],
)
def test_roll_step_is_tracked(payload, rise_s, settle_s, overshoot_deg) -> None:
    """A 10 deg roll step with PX4 main's default gains (MC_ROLL_P 4): measured (empty /
    payload) 90 % rise in 0.41 / 0.42 s, peak 9.8 / 11.2 deg, within 1 deg of the setpoint
    after 0.41 / 1.71 s.

    The arm with payload hangs 0.4 m below the vehicle and multiplies its roll inertia,
    so the default gains respond more slowly there, as they would on the real vehicle.
    """
    plant = TruthPlant.from_scenario(PAPER, "underactuated", payload_attached=payload)
    target = math.radians(10.0)
    thrust = believed_hover_thrust(PAPER, plant.total_mass_kg, target)
    setpoint = AttitudeSetpoint.from_euler(target, 0.0, 0.0, thrust)
    dt = plant.dt_s
    phi = np.array([plant.step(setpoint, [0.0, 0.0]).q[3] for _ in range(round(2.0 / dt))])
    t = np.arange(1, phi.size + 1) * dt
    assert t[np.argmax(phi > 0.9 * target)] < rise_s
    assert np.degrees(phi.max() - target) < overshoot_deg
    assert np.all(np.abs(np.degrees(phi[t > settle_s] - target)) < 1.0)
    # the other axes stay put
    state = plant.state
    assert abs(state.q[4]) < 1e-9 and abs(state.q[5]) < 1e-9


def test_yaw_step_is_tracked() -> None:
    """30 deg yaw step: measured peak 31.9 deg, within 2 deg of the setpoint after 0.64 s."""
    plant = TruthPlant.from_scenario(PAPER, "underactuated", payload_attached=True)
    target = math.radians(30.0)
    setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, target, believed_hover_thrust(PAPER, 1.6))
    psi = np.array([plant.step(setpoint, [0.0, 0.0]).q[5] for _ in range(2000)])
    assert np.degrees(psi.max() - target) < 3.0
    assert np.all(np.abs(np.degrees(psi[1000:] - target)) < 2.0)


def test_joint_torques_are_clipped_to_the_servo_limit() -> None:
    limit = PAPER.plant.servo_torque_limit_n_m
    assert limit == 4.1  # XM430-W350 stall torque at 12 V
    clipped = TruthPlant.from_scenario(PAPER, "underactuated")
    exact = TruthPlant.from_scenario(PAPER, "underactuated")
    setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, 0.4)
    for _ in range(20):
        a = clipped.step(setpoint, [10.0, -25.0])
        b = exact.step(setpoint, [limit, -limit])
    np.testing.assert_array_equal(clipped.actuators.joint_torques_n_m, [limit, -limit])
    np.testing.assert_array_equal(a.q, b.q)
    with pytest.raises(ValueError, match="joint_torques"):
        clipped.step(setpoint, [0.0, math.inf])


def test_rotor_thrust_follows_the_command_with_first_order_lag() -> None:
    """Full thrust from 2 N per rotor: after one time constant 63.2 % of the way there."""
    rotors = PAPER.vehicle.rotors
    plant = TruthPlant.from_scenario(PAPER, "underactuated")
    plant.reset(PAPER.simulation.initial_q, rotor_thrusts_n=np.full(6, 2.0))
    np.testing.assert_allclose(plant.rotor_thrusts_n, 2.0)
    setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, 1.0)
    n = round(rotors.motor_time_constant_s / plant.dt_s)
    applied = []
    for _ in range(n):
        plant.step(setpoint, [0.0, 0.0])
        applied.append(plant.actuators.rotor_thrusts_n.copy())
    t_max = rotors.max_thrust_per_rotor_n * PAPER.plant.thrust_mismatch
    expected = t_max + (2.0 - t_max) * math.exp(-1.0)
    np.testing.assert_allclose(plant.rotor_thrusts_n, expected, rtol=1e-9)
    # the thrust applied during the first step is still the initial one (zero-order hold)
    np.testing.assert_allclose(applied[0], 2.0)
    np.testing.assert_allclose(plant.actuators.motor_commands, 1.0, atol=1e-9)


def test_relative_thrust_is_linear_when_thr_mdl_fac_matches_the_motors() -> None:
    """GIVEN the airframe's THR_MDL_FAC (the motors' curve) WHEN commanding relative thrust r
    THEN the rotors make 6 T_max r; GIVEN THR_MDL_FAC = 0 set live (PX4 not configured for
    these motors) THEN they make 6 T_max (f r^2 + (1 - f) r), the motors' own curve."""
    rotors = PAPER.vehicle.rotors
    plant = TruthPlant.from_scenario(PAPER, "underactuated", payload_attached=True)
    full = 6 * rotors.max_thrust_per_rotor_n

    def settled_thrust(r: float) -> float:
        setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, r)
        for _ in range(600):  # 24 time constants
            plant.step(setpoint, [0.0, 0.0])
        return float(plant.rotor_thrusts_n.sum())

    for r in (0.3, 0.7):
        assert settled_thrust(r) == pytest.approx(full * r, rel=1e-6)
    params = AttitudeLoopParams.from_config(PAPER.plant.attitude_control, thr_mdl_fac=0.0)
    plant.configure_autopilot(params)
    for r in (0.3, 0.7):
        expected = full * thrust_curve(r, rotors.thr_mdl_fac)
        assert settled_thrust(r) == pytest.approx(expected, rel=1e-6)


def test_setpoint_validation_and_euler_constructor() -> None:
    sp = AttitudeSetpoint.from_euler(0.1, -0.2, 0.3, 0.5)
    assert np.linalg.norm(sp.quaternion_wxyz) == pytest.approx(1.0)
    assert AttitudeSetpoint([2.0, 0.0, 0.0, 0.0], 0.5).quaternion_wxyz[0] == 1.0
    with pytest.raises(ValueError, match="thrust"):
        AttitudeSetpoint([1.0, 0.0, 0.0, 0.0], 1.2)
    with pytest.raises(ValueError, match="quaternion"):
        AttitudeSetpoint([0.0, 0.0, 0.0, 0.0], 0.5)
    with pytest.raises(ValueError):
        sp.quaternion_wxyz[0] = 0.0

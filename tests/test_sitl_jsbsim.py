"""sitl.physics.jsbsim: airframe, arm dynamics and coupling, frames, ground, wind, errors.

The cross-validation against the Pinocchio plant is in tests/test_sitl_jsbsim_crossval.py.
"""

import math
from pathlib import Path

import jsbsim
import numpy as np
import pinocchio as pin
import pytest

from sitl.physics import AttitudeSetpoint, BackendError, PlantModeError, make_plant
from sitl.physics.articulation import ETA2_JOINT, build_articulation
from sitl.physics.attitude_control import AttitudeLoopParams
from sitl.physics.jsbsim import GearGeometry, JsbsimPlant, Wind, airframe_xml
from sitl.physics.jsbsim.airframe import AIRCRAFT_NAME, PACKAGE_ROOT
from sitl.physics.jsbsim.arm import ArmDynamics
from sitl.scenario import load_scenario

CONFIGS = Path(__file__).parent.parent / "configs"
FLIGHT = load_scenario(CONFIGS / "paper_sim_flight.toml")
SLUG_KG = 14.593902937
SLUG_FT2_KG_M2 = 1.3558179483


def hover_command(plant) -> float:
    """Relative hover thrust: weight over maximum thrust (PX4 linearizes it)."""
    rotors = FLIGHT.vehicle.rotors
    weight = plant.total_mass_kg * FLIGHT.environment.gravity_m_s2
    return weight / (6 * rotors.max_thrust_per_rotor_n)


# ------------------------------------------------------------------ airframe


def test_shipped_airframe_is_the_generated_one_and_loads_from_the_package() -> None:
    """GIVEN the aircraft file in the package WHEN JSBSim loads it from the package root
    THEN it is what the generator writes for paper_sim_flight, with that vehicle's mass and
    inertia (empty arm point masses)."""
    shipped = PACKAGE_ROOT / "aircraft" / AIRCRAFT_NAME / f"{AIRCRAFT_NAME}.xml"
    assert shipped.read_text() == airframe_xml(FLIGHT)
    jsbsim.FGJSBBase().debug_lvl = 0
    fdm = jsbsim.FGFDMExec(str(PACKAGE_ROOT))
    assert fdm.load_model(AIRCRAFT_NAME)
    fdm["ic/h-agl-ft"] = 3.0
    assert fdm.run_ic()
    assert fdm["inertia/mass-slugs"] * SLUG_KG == pytest.approx(FLIGHT.vehicle.mass_kg, rel=1e-6)
    for axis, value in zip("xyz", FLIGHT.vehicle.inertia_kg_m2, strict=True):
        assert fdm[f"inertia/i{axis}{axis}-slugs_ft2"] * SLUG_FT2_KG_M2 == pytest.approx(
            value, rel=1e-6
        )
    g = FLIGHT.environment.gravity_m_s2
    assert fdm["accelerations/gravity-ft_sec2"] * 0.3048 == pytest.approx(g, rel=1e-6)


def test_another_config_gives_another_airframe() -> None:
    """A heavier vehicle with longer arms: the generated file and JSBSim's mass follow."""
    vehicle = FLIGHT.vehicle.model_copy(
        update={
            "mass_kg": 2.5,
            "rotors": FLIGHT.vehicle.rotors.model_copy(update={"arm_length_m": 0.3}),
        }
    )
    cfg = FLIGHT.model_copy(update={"vehicle": vehicle})
    assert airframe_xml(cfg) != airframe_xml(FLIGHT)
    plant = JsbsimPlant.from_scenario(cfg, payload_attached=True)
    mass = plant.property_value("inertia/mass-slugs") * SLUG_KG
    assert mass == pytest.approx(plant.total_mass_kg, rel=1e-6)
    assert plant.total_mass_kg == pytest.approx(2.5 + 0.1 + 0.1 + 0.4)


# --------------------------------------------------------------------- arm


@pytest.mark.parametrize("seed", range(4))
def test_arm_dynamics_match_pinocchio_on_a_moving_base(seed: int) -> None:
    """GIVEN a random state of the free vehicle + arm + payload and random joint torques
    (no other force but gravity, so the CoM falls freely: b = 0) WHEN Pinocchio's ABA gives
    the base and joint accelerations THEN the independent arm model, fed the body rate and
    its derivative, gives the same joint accelerations, and JSBSim's frozen rigid body plus
    the coupling moment gives the same body angular acceleration."""
    rng = np.random.default_rng(seed)
    art = build_articulation(FLIGHT)
    model = art.model
    model.inertias[ETA2_JOINT] = art.link2_empty + art.payload
    q = pin.randomConfiguration(model, -np.ones(9), np.ones(9))
    q[3:7] /= np.linalg.norm(q[3:7])
    v = rng.normal(size=8)
    tau = np.zeros(8)
    tau[6:8] = rng.normal(size=2)
    acc = pin.aba(model, model.createData(), q, v, tau)
    omega, omega_dot = v[3:6], acc[3:6]

    arm = ArmDynamics(FLIGHT, 1e-3)
    arm.set_payload(True)
    arm.eta, arm.eta_dot = q[7:9].tolist(), v[6:8].tolist()
    c, _ = (np.array(x) for x in arm.centre_of_mass())
    masses = arm.point_masses()
    moment = arm.step(tuple(tau[6:8]), (0.0, 0.0, 0.0), tuple(omega), tuple(omega_dot))
    np.testing.assert_allclose(arm.eta_ddot, acc[6:8], rtol=1e-10, atol=1e-10)

    inertia = np.diag(FLIGHT.vehicle.inertia_kg_m2) + FLIGHT.vehicle.mass_kg * (
        c @ c * np.eye(3) - np.outer(c, c)
    )
    for m, s in masses:
        rho = np.array(s) - c
        inertia += m * (rho @ rho * np.eye(3) - np.outer(rho, rho))
    frozen = inertia @ omega_dot + np.cross(omega, inertia @ omega)
    np.testing.assert_allclose(frozen, moment, atol=1e-10)


def test_two_point_masses_carry_the_link_inertia() -> None:
    """Link 1 (uniform rod) and link 2 + payload as point masses: same theta as the config."""
    arm = ArmDynamics(FLIGHT, 1e-3)
    arm.set_payload(True)
    truth = FLIGHT.true_theta
    assert arm.link2.theta.m2_kg == pytest.approx(truth.m2_kg)
    assert arm.link2.theta.m3_kg_m == pytest.approx(truth.m3_kg_m)
    assert arm.link2.theta.m4_kg_m2 == pytest.approx(truth.m4_kg_m2)
    (m_a, a), (m_b, b) = arm.link1.point_masses()
    rod = FLIGHT.arm.link1
    assert m_a * a * a + m_b * b * b == pytest.approx(
        rod.inertia_about_com_kg_m2 + rod.mass_kg * rod.com_m**2
    )


@pytest.mark.parametrize("config", ["paper_sim_flight.toml", "experiment_arm.toml"])
def test_lagged_coupling_contracts_in_every_pose(config: str) -> None:
    """The one-step-lag loop gain (arm module docstring) is below 1 in every arm pose, with
    and without payload: an error in the lagged base acceleration dies out."""
    cfg = load_scenario(CONFIGS / config)
    arm = ArmDynamics(cfg, 1e-3)
    worst = 0.0
    for attached in (False, True):
        arm.set_payload(attached)
        for e1 in np.linspace(-math.pi, math.pi, 9):
            for e2 in np.linspace(-math.pi, math.pi, 9):
                arm.eta = [float(e1), float(e2)]
                worst = max(worst, arm.coupling_ratio())
    assert 0.0 < worst < 0.8


# ------------------------------------------------------------------- plant


def test_reset_round_trips_the_state_through_jsbsim() -> None:
    """q, q_dot set through JSBSim's initial conditions (CG, NED/FRD, feet) read back."""
    plant = JsbsimPlant.from_scenario(FLIGHT, payload_attached=True)
    q = np.array([0.3, -1.2, 1.5, 0.2, -0.3, 2.9, -1.2, 0.4])
    q_dot = np.array([0.4, -0.2, 0.3, 0.5, -0.4, 0.3, 0.8, -0.6])
    state = plant.reset(q, q_dot, time_s=2.0)
    np.testing.assert_allclose(state.q, q, atol=1e-8)
    np.testing.assert_allclose(state.q_dot, q_dot, atol=1e-8)
    assert state.time_s == 2.0
    assert plant.property_value("inertia/mass-slugs") * SLUG_KG == pytest.approx(1.6, rel=1e-6)


def test_hover_holds_still() -> None:
    """At the relative hover thrust, level: JSBSim's gravity, masses and rotor forces
    balance (drift below 0.1 mm in 2 s)."""
    plant = JsbsimPlant.from_scenario(FLIGHT, payload_attached=True)
    setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, hover_command(plant))
    for _ in range(2000):
        state = plant.step(setpoint, [0.0, 0.0])
    np.testing.assert_allclose(state.q, FLIGHT.simulation.initial_q, atol=1e-4)
    np.testing.assert_allclose(state.q_dot, 0.0, atol=1e-4)


def test_autopilot_takes_thr_mdl_fac_live() -> None:
    """PX4 with THR_MDL_FAC 0 on motors of curve 0.3 (set live): the relative hover thrust
    makes only f r^2 + (1 - f) r of full thrust per rotor, as on the Pinocchio plant."""
    plant = JsbsimPlant.from_scenario(FLIGHT, payload_attached=True)
    plant.configure_autopilot(
        AttitudeLoopParams.from_config(FLIGHT.plant.attitude_control, thr_mdl_fac=0.0)
    )
    r = hover_command(plant)
    setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, r)
    for _ in range(600):
        plant.step(setpoint, [0.0, 0.0])
    f = FLIGHT.vehicle.rotors.thr_mdl_fac
    full = 6 * FLIGHT.vehicle.rotors.max_thrust_per_rotor_n
    assert plant.rotor_thrusts_n.sum() == pytest.approx(full * (f * r * r + (1 - f) * r), rel=1e-3)


def test_vehicle_lands_on_its_gear() -> None:
    """Thrust off: the vehicle falls from 0.7 m and comes to rest on its four feet, the CoM
    at the gear height above the ground (spring deflection below 5 mm)."""
    gear = GearGeometry()
    plant = JsbsimPlant.from_scenario(FLIGHT, gear=gear)
    setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, 0.0)
    for _ in range(3000):
        state = plant.step(setpoint, [0.0, 0.0])
    assert gear.height_m - 0.005 < state.q[2] < gear.height_m
    assert np.abs(state.q_dot[0:3]).max() < 1e-3
    assert abs(state.q[3]) < 1e-3 and abs(state.q[4]) < 1e-3


def test_a_flipped_vehicle_lands_on_its_rotor_hubs() -> None:
    """Upside down with the rotors off: it comes to rest on the hub contacts, the vehicle
    CoM just above the ground (not hanging from its feet below it)."""
    plant = JsbsimPlant.from_scenario(FLIGHT)
    q = np.array([0.0, 0.0, 0.5, math.pi, 0.0, 0.0, -math.pi / 2, 0.0])
    plant.reset(q, rotor_thrusts_n=np.zeros(6))
    setpoint = AttitudeSetpoint.from_euler(math.pi, 0.0, 0.0, 0.0)
    for _ in range(2000):
        state = plant.step(setpoint, [0.0, 0.0])
    assert -0.005 < state.q[2] < 0.01
    assert np.abs(state.q_dot[0:3]).max() < 1e-2


def test_steady_wind_pushes_through_the_drag() -> None:
    """A 2 m/s wind toward the east on a level, hovering vehicle: its CoM accelerates east
    at D_x w / m (the vehicle body, O, first faster: the hanging arm lags), and not north."""
    wind = Wind(velocity_enu_m_s=(2.0, 0.0, 0.0))
    plant = JsbsimPlant.from_scenario(FLIGHT, payload_attached=True, wind=wind)
    setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, hover_command(plant))
    for _ in range(50):
        state = plant.step(setpoint, [0.0, 0.0])
    com_east_m_s = plant.property_value("velocities/v-east-fps") * 0.3048
    expected = FLIGHT.plant.linear_drag_n_s_m[0] * 2.0 / plant.total_mass_kg
    assert com_east_m_s / state.time_s == pytest.approx(expected, rel=0.02)
    assert state.q_dot[0] > com_east_m_s
    assert abs(state.q_dot[1]) < 1e-6


def test_turbulence_shakes_the_vehicle() -> None:
    """Dryden turbulence on top of a 3 m/s wind: the air velocity fluctuates (JSBSim's
    total wind) and the run stays finite."""
    wind = Wind((3.0, 0.0, 0.0), "milspec", windspeed_20ft_m_s=7.7, seed=1)
    plant = JsbsimPlant.from_scenario(FLIGHT, payload_attached=True, wind=wind)
    setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, hover_command(plant))
    north = []
    for _ in range(1000):
        state = plant.step(setpoint, [0.0, 0.0])
        north.append(plant.property_value("atmosphere/total-wind-north-fps") * 0.3048)
    assert np.std(north) > 0.01
    assert np.all(np.isfinite(state.q))


def test_payload_grasp_keeps_the_vehicle_in_place() -> None:
    """Grasping changes theta and the mass but not q (JSBSim is restarted at the same q)."""
    plant = JsbsimPlant.from_scenario(FLIGHT)
    before = plant.state.q
    plant.attach_payload()
    np.testing.assert_allclose(plant.state.q, before, atol=1e-8)
    assert plant.true_theta.m2_kg == pytest.approx(0.5)
    with pytest.raises(Exception, match="already attached"):
        plant.attach_payload()
    plant.detach_payload()
    assert plant.true_theta.m2_kg == pytest.approx(0.1)
    # On the ground JSBSim's link 2 takes none of it, then all of it at once.
    plant.attach_payload(share=0.0)
    assert plant.payload_attached and plant.true_theta.m2_kg == pytest.approx(0.1)
    plant.set_payload_share(0.9)
    assert plant.true_theta.m2_kg == pytest.approx(0.1)
    plant.set_payload_share(1.0)
    assert plant.true_theta.m2_kg == pytest.approx(0.5)


# ------------------------------------------------------------------ errors


def test_ideal_mode_is_pinocchio_only() -> None:
    with pytest.raises(BackendError, match=r"ideal mode .* only with physics='pinocchio'"):
        make_plant(FLIGHT, "jsbsim", "ideal")
    with pytest.raises(PlantModeError, match="only mode 'underactuated'"):
        JsbsimPlant.from_scenario(FLIGHT, mode="ideal")


def test_turbulence_is_jsbsim_only_wind_underactuated_only_and_unknown_backends_refused() -> None:
    with pytest.raises(BackendError, match="turbulence needs physics='jsbsim'"):
        make_plant(FLIGHT, "pinocchio", wind=Wind((1.0, 0.0, 0.0), "milspec", 7.7))
    with pytest.raises(BackendError, match="wind needs mode='underactuated'"):
        make_plant(FLIGHT, "pinocchio", "ideal", wind=Wind((1.0, 0.0, 0.0)))
    windy = FLIGHT.model_copy(
        update={"plant": FLIGHT.plant.model_copy(update={"wind_m_s": (0.0, 2.0, 0.0)})}
    )
    with pytest.raises(BackendError, match="wind needs mode='underactuated'"):
        make_plant(windy, "pinocchio", "ideal")
    assert make_plant(windy, "jsbsim").wind.velocity_enu_m_s == (0.0, 2.0, 0.0)  # type: ignore[union-attr]
    with pytest.raises(BackendError, match="physics must be one of"):
        make_plant(FLIGHT, "mujoco")  # type: ignore[arg-type]
    assert type(make_plant(FLIGHT, "jsbsim")).__name__ == "JsbsimPlant"
    assert type(make_plant(FLIGHT, "pinocchio", "ideal")).__name__ == "TruthPlant"


def test_wind_options_are_validated() -> None:
    with pytest.raises(ValueError, match="needs windspeed_20ft_m_s > 0"):
        Wind(turbulence="milspec")
    with pytest.raises(ValueError, match="turbulence must be one of"):
        Wind(turbulence="tustin")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="3 finite values"):
        Wind(velocity_enu_m_s=(1.0, math.nan, 0.0))


# --------------------------------------------------------------- command line


def test_cli_refuses_jsbsim_ideal_turbulence_on_pinocchio_and_wind_on_ideal(
    run_sitl, tmp_path: Path
) -> None:
    scenario = str(CONFIGS / "paper_sim_flight.toml")
    ideal = run_sitl("sim", "--scenario", scenario, "--out", str(tmp_path), "--physics", "jsbsim")
    assert ideal.returncode == 2
    assert "--physics jsbsim needs --plant underactuated" in ideal.stderr
    turbulent = run_sitl(
        "compare", "--scenario", scenario, "--out", str(tmp_path), "--plant", "underactuated",
        "--turbulence", "7.7",
    )  # fmt: skip
    assert turbulent.returncode == 2
    assert "--turbulence needs --physics jsbsim" in turbulent.stderr
    windy = run_sitl("sim", "--scenario", scenario, "--out", str(tmp_path), "--wind", "3,0,0")
    assert windy.returncode == 2
    assert "wind needs --plant underactuated" in windy.stderr
    bad = run_sitl(
        "sim", "--scenario", scenario, "--out", str(tmp_path), "--plant", "underactuated",
        "--physics", "jsbsim", "--wind", "3,0",
    )  # fmt: skip
    assert bad.returncode == 2
    assert "three values E,N,U" in bad.stderr


def test_cli_sim_on_jsbsim_with_wind(run_sitl, tmp_path: Path) -> None:
    """companion sim --physics jsbsim --wind --turbulence: the run is recorded as such."""
    import json

    result = run_sitl(
        "sim", "--scenario", str(CONFIGS / "paper_sim_flight.toml"), "--out", str(tmp_path),
        "--plant", "underactuated", "--physics", "jsbsim", "--wind", "2,1,0",
        "--turbulence", "5", "--duration", "1",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["physics"] == "jsbsim"
    assert summary["wind"]["velocity_enu_m_s"] == [2.0, 1.0, 0.0]
    assert summary["wind"]["turbulence"] == "milspec"
    assert "jsbsim, wind" in result.stdout

"""sitl: fixed-seed trajectories of the truth plant and of the SITL vehicle against a record.

The SITL's step was made faster (the plant's float arithmetic in a compiled
kernel, fewer per-step allocations); these runs pin what it computes. The record,
``tests/data/sitl_regression.npz``, was written by the code before that work (``python
tests/test_sitl_regression.py`` rewrites it, for a deliberate change of the physics).

- the ideal plant (paper scenario) under a PD law tracking a moving reference, with the
  payload grasped and released mid-run, for both integrators;
- the underactuated plant (PX4-like loop, mixer with desaturation, rotor lag, servo
  limit, a small draining battery) under tilts, a yaw turn through pi, saturating thrust,
  joint steps beyond the servo limit, a PARAM_SET and then outside motor commands, for both
  integrators;
- the SITL vehicle of ``configs/sitl_pickup.toml`` without its sockets: noisy navigation
  (seed 1), the PX4 imitation armed and taking off, the world with its XM430 servo models,
  gripper and ground, and every telemetry message it builds.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from sitl.physics import AttitudeSetpoint, TruthPlant
from sitl.physics.attitude_control import AttitudeLoopParams
from sitl.scenario import Battery, Scenario, load_scenario

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
RECORD = Path(__file__).resolve().parent / "data" / "sitl_regression.npz"
INTEGRATORS = ("semi_implicit_euler", "rk4")


def _with_plant(cfg: Scenario, **changes) -> Scenario:
    return cfg.model_copy(update={"plant": cfg.plant.model_copy(update=changes)})


def ideal_run(integrator: str) -> np.ndarray:
    """Rows [q, q_dot, q_ddot] every 10th of 3000 steps (paper scenario, ideal mode)."""
    cfg = _with_plant(load_scenario(CONFIGS / "paper_sim.toml"), integrator=integrator)
    plant = TruthPlant.from_scenario(cfg, "ideal")
    q0 = np.array(cfg.simulation.initial_q)
    kp = np.array([4.0, 4.0, 8.0, 2.0, 2.0, 2.0, 3.0, 3.0])
    kd = np.array([3.0, 3.0, 5.0, 0.5, 0.5, 0.5, 0.5, 0.5])
    rows = []
    state = plant.state
    for k in range(3000):
        t = k * plant.dt_s
        ref = q0 + np.array(
            [
                *(0.5 * math.sin(t), 0.3 * math.cos(2 * t) - 0.3, 0.2 * math.sin(3 * t)),
                *(0.2 * math.sin(2 * t), 0.15 * math.sin(1.5 * t), 2.0 * t),
                *(0.8 * math.sin(2.5 * t), 0.6 * math.sin(3 * t)),
            ]
        )
        tau = -kp * (state.q - ref) - kd * state.q_dot
        tau[2] += plant.total_mass_kg * cfg.environment.gravity_m_s2
        if k == 1000:
            plant.attach_payload()
        if k == 2000:
            plant.detach_payload()
        state = plant.step_ideal(tau)
        if k % 10 == 0:
            rows.append(np.concatenate((state.q, state.q_dot, state.q_ddot)))
    return np.array(rows)


def underactuated_run(integrator: str) -> np.ndarray:
    """Rows [q, q_dot, q_ddot, quaternion, omega, motor commands, rotor thrusts, joint
    torques, rate setpoint, normalized torques] every 10th of 4000 steps."""
    cfg = _with_plant(
        load_scenario(CONFIGS / "sitl_pickup.toml"),
        integrator=integrator,
        battery=Battery(capacity_ah=0.05, resistance_ohm=0.05, start_charge=0.6),
    )
    plant = TruthPlant.from_scenario(cfg, "underactuated", payload_attached=True)
    rotors = cfg.vehicle.rotors
    hover = plant.total_mass_kg * cfg.environment.gravity_m_s2 / (6 * rotors.max_thrust_per_rotor_n)
    rows = []
    state = plant.state
    for k in range(4000):
        t = k * plant.dt_s
        if k == 1500:  # PARAM_SET: stiffer roll, another THR_MDL_FAC
            loop = cfg.plant.attitude_control
            params = AttitudeLoopParams.from_config(loop, 0.5 * rotors.thr_mdl_fac)
            plant.configure_autopilot(
                AttitudeLoopParams(**{**params.__dict__, "attitude_p": (9.0, 6.5, 2.8)})
            )
        # joint PD toward steps that ask for more than the servo limit at each switch
        ref = (-1.2, 0.3) if (k // 700) % 2 else (-0.4, -0.5)
        q, qd = state.q, state.q_dot
        joints = [-8.0 * (q[6] - ref[0]) - 0.4 * qd[6], -8.0 * (q[7] - ref[1]) - 0.3 * qd[7]]
        if k < 3500:
            thrust = min(1.0, hover * (1.0 + 0.6 * math.sin(4 * t)))  # saturates at times
            setpoint = AttitudeSetpoint.from_euler(
                0.3 * math.sin(3 * t), -0.25 * math.cos(2 * t), 1.5 * t + 2.5, thrust
            )
            state = plant.step(setpoint, joints)
        else:
            commands = [0.5 + 0.1 * math.sin(7 * t + i) for i in range(6)]
            state = plant.step_motors(commands, joints)
        if k % 10 == 0:
            act = plant.actuators
            rows.append(
                np.concatenate(
                    (
                        state.q,
                        state.q_dot,
                        state.q_ddot,
                        state.quaternion_wxyz,
                        state.omega_body_rad_s,
                        act.motor_commands,
                        act.rotor_thrusts_n,
                        act.joint_torques_n_m,
                        np.nan_to_num(act.rate_setpoint_rad_s, nan=-99.0),
                        np.nan_to_num(act.torque_normalized, nan=-99.0),
                    )
                )
            )
    return np.array(rows)


def vehicle_run() -> tuple[np.ndarray, np.ndarray]:
    """The SITL vehicle's step without sockets for 4 s after a take-off command: rows
    [q, q_dot, servo torques, gripper angle, estimate position, estimate velocity] every
    20th step, and every telemetry message but SYSTEM_TIME (wall clock) as its id and
    numeric fields, one flat array."""
    from pymavlink.dialects.v20 import common as mavlink

    from sitl.px4 import GeoReference, Px4Params, Px4Vehicle
    from sitl.vehicle.navigation import Navigation
    from sitl.vehicle.options import RunOptions
    from sitl.vehicle.runner import build_world

    scenario = load_scenario(CONFIGS / "sitl_pickup.toml")
    options = RunOptions(seed=1, navigation="gps")
    world, _bus, _joints, _gripper = build_world(scenario, options)
    overrides = dict(scenario.world.autopilot_params) if scenario.world else {}
    params = Px4Params.from_scenario(scenario, overrides)
    navigation = Navigation(
        scenario,
        np.random.default_rng(1),
        mode="gps",
        noise=True,
        imu_rate_hz=params["IMU_INTEG_RATE"],
    )
    autopilot = Px4Vehicle(
        params,
        system_id=int(params["MAV_SYS_ID"]),
        geo=GeoReference(),
        aiding=navigation.report.aiding,
        unix_time_at_boot_us=1_700_000_000_000_000,
    )
    client = mavlink.MAVLink(None, 255, 190)
    rows: list[np.ndarray] = []
    sent: list[float] = []
    for k in range(4500):
        now_s = world.time_s
        if k == 500:  # arm, then NAV_TAKEOFF, as from the onboard link
            for command in (
                mavlink.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
                mavlink.MAVLink_command_long_message(1, 1, 22, 0, 0, 0, 0, 0, *[float("nan")] * 3),
            ):
                msg = mavlink.MAVLink(None).parse_buffer(command.pack(client))[0]
                autopilot.handle(msg, "onboard", now_s)
        measurement = navigation.measure(world)
        setpoint = autopilot.control(now_s, measurement)
        world.step(setpoint)
        for _link, message in autopilot.telemetry(now_s, measurement):
            if message.get_type() != "SYSTEM_TIME":
                sent += _numbers(message)
        if k % 20 == 0:
            truth = world.truth()
            rows.append(
                np.concatenate(
                    (
                        truth.plant.q,
                        truth.plant.q_dot,
                        truth.joint_torques_n_m,
                        [truth.gripper_angle_rad or 0.0],
                        measurement.position_enu_m,
                        measurement.velocity_enu_m_s,
                    )
                )
            )
    return np.array(rows), np.array(sent)


def _numbers(message) -> list[float]:
    """A MAVLink message's id and numeric field values (arrays flattened), in field order."""
    out = [float(message.get_msgId())]
    for name in message.get_fieldnames():
        value = getattr(message, name)
        values = value if isinstance(value, list) else [value]
        out += [float(v) for v in values if isinstance(v, int | float)]
    return out


def record() -> dict[str, np.ndarray]:
    """Every run of this module by name."""
    out = {f"ideal_{i}": ideal_run(i) for i in INTEGRATORS}
    out |= {f"underactuated_{i}": underactuated_run(i) for i in INTEGRATORS}
    out["vehicle"], out["vehicle_telemetry"] = vehicle_run()
    return out


@pytest.fixture(scope="module")
def recorded() -> dict[str, np.ndarray]:
    with np.load(RECORD) as data:
        return dict(data)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_ideal_plant_follows_the_record(recorded, integrator) -> None:
    np.testing.assert_allclose(ideal_run(integrator), recorded[f"ideal_{integrator}"], atol=1e-9)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_underactuated_plant_follows_the_record(recorded, integrator) -> None:
    np.testing.assert_allclose(
        underactuated_run(integrator), recorded[f"underactuated_{integrator}"], atol=1e-9
    )


def test_sitl_vehicle_follows_the_record(recorded) -> None:
    rows, telemetry = vehicle_run()
    np.testing.assert_allclose(rows, recorded["vehicle"], atol=1e-9)
    # float32 fields: one rounding step of a value that moved by 1e-15
    np.testing.assert_allclose(telemetry, recorded["vehicle_telemetry"], rtol=1e-6, atol=1e-6)
    assert rows[-1, 2] > 1.0  # it took off: the run exercised flight, not the ground only


if __name__ == "__main__":
    RECORD.parent.mkdir(exist_ok=True)
    np.savez_compressed(RECORD, **record())
    print(f"wrote {RECORD}", file=sys.stderr)

"""Per-step cost of the SITL truth plant (sitl.physics) in both modes.

Runs the paper scenario for its 10 s at the configured plant rate:

- ideal mode: a PD law on q plus gravity feed-forward, tau conjugate to q (as the paper's
  simulation feeds its controller output), with ``plant.state`` read every step;
- underactuated mode: a level attitude setpoint at the relative hover thrust
  and zero joint torques, also reading the state every step;

and prints the median and 99th percentile of the step time (step + state) in
microseconds and the wall time of the whole loop, for each integrator.

Usage: ``python benchmarks/bench_plant.py [path/to/scenario.toml]``
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from sitl.physics import AttitudeSetpoint, TruthPlant
from sitl.scenario import Scenario, load_scenario

DEFAULT = Path(__file__).resolve().parent.parent / "configs" / "paper_sim.toml"


def _report(label: str, samples_ns: list[int], wall_s: float) -> None:
    us = np.array(samples_ns) / 1e3
    print(
        f"{label:<38} steps {len(us):6d}  median {np.median(us):7.1f} us  "
        f"p99 {np.percentile(us, 99):7.1f} us  loop {wall_s:6.3f} s"
    )


def bench_ideal(scenario: Scenario) -> None:
    plant = TruthPlant.from_scenario(scenario, "ideal", payload_attached=True)
    q_ref = np.array(scenario.simulation.initial_q)
    weight = plant.total_mass_kg * scenario.environment.gravity_m_s2
    kp = np.array([4.0, 4.0, 8.0, 2.0, 2.0, 2.0, 3.0, 3.0])
    kd = np.array([3.0, 3.0, 5.0, 0.5, 0.5, 0.5, 0.5, 0.5])
    n = round(scenario.simulation.duration_s * plant.rate_hz)
    samples = []
    state = plant.state
    start = time.perf_counter()
    for _ in range(n):
        tau = -kp * (state.q - q_ref) - kd * state.q_dot
        tau[2] += weight
        t0 = time.perf_counter_ns()
        plant.step_ideal(tau)
        state = plant.state
        samples.append(time.perf_counter_ns() - t0)
    wall = time.perf_counter() - start
    _report(f"ideal / {scenario.plant.integrator}", samples, wall)


def bench_underactuated(scenario: Scenario) -> None:
    plant = TruthPlant.from_scenario(scenario, "underactuated", payload_attached=True)
    rotors = scenario.vehicle.rotors
    rel = (
        plant.total_mass_kg
        * scenario.environment.gravity_m_s2
        / (6 * rotors.max_thrust_per_rotor_n * scenario.plant.thrust_mismatch)
    )
    setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, rel)  # relative thrust (PX4)
    joints = np.zeros(2)
    n = round(scenario.simulation.duration_s * plant.rate_hz)
    samples = []
    start = time.perf_counter()
    for _ in range(n):
        t0 = time.perf_counter_ns()
        plant.step(setpoint, joints)
        _ = plant.state
        samples.append(time.perf_counter_ns() - t0)
    wall = time.perf_counter() - start
    _report(f"underactuated / {scenario.plant.integrator}", samples, wall)


def main(argv: list[str]) -> None:
    scenario = load_scenario(argv[1] if len(argv) > 1 else DEFAULT)
    duration, rate = scenario.simulation.duration_s, scenario.plant.rate_hz
    print(f"scenario {scenario.name}: {duration:g} s at {rate:g} Hz")
    for integrator in ("semi_implicit_euler", "rk4"):
        cfg = scenario.model_copy(
            update={"plant": scenario.plant.model_copy(update={"integrator": integrator})}
        )
        bench_ideal(cfg)
        bench_underactuated(cfg)


if __name__ == "__main__":
    main(sys.argv)

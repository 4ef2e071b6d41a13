"""Real-time factor of the JSBSim physics backend beside the Pinocchio plant, at 1 kHz.

Flies the paper flight scenario (configs/paper_sim_flight.toml, payload grasped) for
10 simulated seconds on each backend in underactuated mode: a level attitude setpoint at
the relative hover thrust while the servos swing the arm (PD on a 0.5 Hz sinusoid),
reading ``plant.state`` every step, as the offline simulator and the SITL vehicle do. The
JSBSim backend is also run in wind with Dryden turbulence. Prints, per backend, the
median and 99th percentile of one step (step + state) in microseconds and the real-time
factor (simulated seconds per wall-clock second; above 1 is faster than real time).

Usage: ``python benchmarks/bench_jsbsim.py [path/to/scenario.toml] [seconds]``
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

from sitl.physics import AttitudeSetpoint, make_plant
from sitl.physics.jsbsim import Wind
from sitl.scenario import Scenario, load_scenario

DEFAULT = Path(__file__).resolve().parent.parent / "configs" / "paper_sim_flight.toml"


def run(scenario: Scenario, physics: str, seconds: float, wind: Wind | None = None) -> None:
    plant = make_plant(scenario, physics, "underactuated", payload_attached=True, wind=wind)
    rotors = scenario.vehicle.rotors
    rel = (
        plant.total_mass_kg
        * scenario.environment.gravity_m_s2
        / (6 * rotors.max_thrust_per_rotor_n)
    )
    setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, 0.0, rel)  # relative thrust (PX4)
    n = round(seconds * plant.rate_hz)
    samples = np.empty(n)
    state = plant.state
    start = time.perf_counter()
    for i in range(n):
        t = i * plant.dt_s
        ref = (-math.pi / 2 + 0.4 * math.sin(math.pi * t), 0.3 * math.sin(math.pi * t))
        torques = (
            4.0 * (ref[0] - state.q[6]) - 0.4 * state.q_dot[6],
            4.0 * (ref[1] - state.q[7]) - 0.4 * state.q_dot[7],
        )
        t0 = time.perf_counter_ns()
        plant.step(setpoint, torques)
        state = plant.state
        samples[i] = time.perf_counter_ns() - t0
    wall = time.perf_counter() - start
    us = samples / 1e3
    label = f"{physics}{' + wind, turbulence' if wind else ''} @ {plant.rate_hz:g} Hz"
    print(
        f"{label:<36} median {np.median(us):6.1f} us  p99 {np.percentile(us, 99):6.1f} us  "
        f"real-time factor {seconds / wall:5.2f} (plant steps only: "
        f"{seconds / (samples.sum() / 1e9):5.2f})"
    )


def main() -> None:
    scenario = load_scenario(sys.argv[1] if len(sys.argv) > 1 else DEFAULT)
    seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 10.0
    print(f"{scenario.name}: {seconds:g} s simulated, arm swinging, state read every step")
    run(scenario, "pinocchio", seconds)
    run(scenario, "jsbsim", seconds)
    run(scenario, "jsbsim", seconds, Wind((3.0, 0.0, 0.0), "milspec", 7.7))


if __name__ == "__main__":
    main()

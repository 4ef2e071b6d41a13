"""Per-step cost of the SITL truth plant (sitl.physics) in both modes, and its share of the
10 s offline paper run.

Runs the paper scenario for its 10 s at the configured plant rate:

- ideal mode: a PD law on q plus gravity feed-forward, tau conjugate to q (as the paper's
  simulation feeds its controller output), with ``plant.state`` read every step;
- underactuated mode: a level attitude setpoint at the relative hover thrust
  and zero joint torques, also reading the state every step;

and prints the median and 99th percentile of the step time (step + state) in
microseconds, the CPU time per step (this process's CPU time over the loop, less
sensitive than wall time to other processes on a loaded machine) and the wall time of the
whole loop, for each integrator. Then the offline paper run (``sitl.offline.simulate``,
passivity + paper estimator, ideal plant): its wall and CPU time, best of ``--repeat``,
and the plant's share of it (the ideal, semi-implicit-Euler loop above is its plant side:
10 s of ``step_ideal`` + ``state``).

``--before DIR`` runs the same measurements on the code in DIR (a checkout of an earlier
commit with its C extensions built in place, e.g. ``git worktree add /tmp/before a08a115
&& cd /tmp/before && python setup.py build_ext --inplace``) in a subprocess, alternating
with this code, and prints both side by side (best of the runs for each).

Usage: ``python benchmarks/bench_plant.py [--config scenario.toml] [--repeat 3]
[--before DIR]``
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
from checkout import now_and_before

DEFAULT = Path(__file__).resolve().parent.parent / "configs" / "paper_sim.toml"
INTEGRATORS = ("semi_implicit_euler", "rk4")


def bench_ideal(scenario) -> dict[str, float]:
    from sitl.physics import TruthPlant

    plant = TruthPlant.from_scenario(scenario, "ideal", payload_attached=True)
    q_ref = np.array(scenario.simulation.initial_q)
    weight = plant.total_mass_kg * scenario.environment.gravity_m_s2
    kp = np.array([4.0, 4.0, 8.0, 2.0, 2.0, 2.0, 3.0, 3.0])
    kd = np.array([3.0, 3.0, 5.0, 0.5, 0.5, 0.5, 0.5, 0.5])
    n = round(scenario.simulation.duration_s * plant.rate_hz)
    samples = []
    state = plant.state
    start, cpu0 = time.perf_counter(), time.process_time()
    for _ in range(n):
        tau = -kp * (state.q - q_ref) - kd * state.q_dot
        tau[2] += weight
        t0 = time.perf_counter_ns()
        plant.step_ideal(tau)
        state = plant.state
        samples.append(time.perf_counter_ns() - t0)
    return _figures(samples, time.perf_counter() - start, time.process_time() - cpu0)


def bench_underactuated(scenario) -> dict[str, float]:
    from sitl.physics import AttitudeSetpoint, TruthPlant

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
    start, cpu0 = time.perf_counter(), time.process_time()
    for _ in range(n):
        t0 = time.perf_counter_ns()
        plant.step(setpoint, joints)
        _ = plant.state
        samples.append(time.perf_counter_ns() - t0)
    return _figures(samples, time.perf_counter() - start, time.process_time() - cpu0)


def _figures(samples_ns: list[int], wall_s: float, cpu_s: float) -> dict[str, float]:
    us = np.array(samples_ns) / 1e3
    return {
        "median_us": float(np.median(us)),
        "p99_us": float(np.percentile(us, 99)),
        "cpu_us": cpu_s / len(us) * 1e6,
        "cpu_s": cpu_s,
        "loop_s": wall_s,
    }


def offline_run(scenario) -> dict[str, float]:
    from sitl.offline.simulation import SimOptions, simulate

    options = SimOptions(controller="passivity", estimator="paper")
    start, cpu0 = time.perf_counter(), time.process_time()
    simulate(scenario, options)
    return {"wall_s": time.perf_counter() - start, "cpu_s": time.process_time() - cpu0}


def measure(config: Path, repeat: int) -> dict[str, dict[str, float]]:
    """Every figure, each the best of ``repeat`` runs (noise only ever adds time)."""
    from sitl.scenario import load_scenario

    scenario = load_scenario(config)
    out: dict[str, dict[str, float]] = {}
    for integrator in INTEGRATORS:
        cfg = scenario.model_copy(
            update={"plant": scenario.plant.model_copy(update={"integrator": integrator})}
        )
        for mode, bench in (("ideal", bench_ideal), ("underactuated", bench_underactuated)):
            runs = [bench(cfg) for _ in range(repeat)]
            out[f"{mode} / {integrator}"] = {k: min(r[k] for r in runs) for k in runs[0]}
    runs = [offline_run(scenario) for _ in range(repeat)]
    out["offline"] = {k: min(r[k] for r in runs) for k in runs[0]}
    return out


def _best(a: dict, b: dict) -> dict:
    return {key: {k: min(a[key][k], b[key][k]) for k in a[key]} for key in a}


def _print(label: str, now: dict, before: dict | None) -> None:
    print(f"\n{label}")
    head = f"{'':<34} {'median':>8} {'p99':>8} {'CPU/step':>9} {'loop':>8}"
    print(head + ("   before: median  CPU/step" if before else ""))
    for key in (f"{m} / {i}" for i in INTEGRATORS for m in ("ideal", "underactuated")):
        f = now[key]
        line = (
            f"{key:<34} {f['median_us']:6.1f}us {f['p99_us']:6.1f}us {f['cpu_us']:7.1f}us "
            f"{f['loop_s']:6.3f}s"
        )
        if before:
            b = before[key]
            line += f"   {b['median_us']:11.1f}us {b['cpu_us']:7.1f}us"
        print(line)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=DEFAULT)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--before", type=Path, help="checkout of the code to compare with")
    parser.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.json:
        print(json.dumps(measure(args.config, args.repeat)))
        return
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    now, before = now_and_before(
        lambda: measure(args.config, args.repeat), args.before, __file__,
        ["--config", str(args.config), "--repeat", str(args.repeat)], _best,
    )  # fmt: skip
    _print(f"Truth plant, {args.config.name}, 10 s, step + state, best of runs", now, before)

    plant_side = now["ideal / semi_implicit_euler"]
    offline = now["offline"]
    print("\n10 s offline paper run (passivity + paper estimator, ideal plant)")
    rows = [("now", plant_side, offline)]
    if before is not None:
        rows.insert(0, ("before", before["ideal / semi_implicit_euler"], before["offline"]))
    for label, plant, run in rows:
        print(
            f"{label:<7} wall {run['wall_s']:5.2f} s  CPU {run['cpu_s']:5.2f} s  "
            f"plant side {plant['loop_s']:5.3f} s wall ({plant['cpu_s']:5.3f} s CPU)"
            f" = {plant['cpu_s'] / run['cpu_s']:4.0%} of the run's CPU"
        )


if __name__ == "__main__":
    main()

"""Cost of one control step and of the whole offline simulation.

Runs ``sitl.offline.simulate`` on the paper scenario (10 s, ideal plant, exact
measurements) for passivity + paper estimator, passivity + RLS and the adaptive
sliding-mode controller, and prints for each

- the median and 99th percentile of one control step as the simulator times it (feed the
  measurements to the state filter, read q, q_dot, q_ddot, model terms, estimator,
  desired state, controller, setpoint mapping, tilt reference), in microseconds;
- the wall time of the whole run (control steps, truth plant at ``plant.rate_hz``,
  logging).

Each run is repeated ``--repeat`` times; the best wall time and the step statistics of
that run are printed (the machine's noise only ever adds time). The truth plant's own cost
is printed by ``benchmarks/bench_plant.py``.
Targets (tracker): <= 50 us median per control step, <= 2 s wall for the 10 s run.

Usage: ``python benchmarks/bench_control_step.py [--config configs/paper_sim.toml]
[--repeat 3]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from sitl.offline import SimOptions, simulate
from sitl.scenario import load_scenario

DEFAULT = Path(__file__).resolve().parent.parent / "configs" / "paper_sim.toml"
RUNS = {
    "passivity + paper": SimOptions(controller="passivity", estimator="paper"),
    "passivity + rls": SimOptions(controller="passivity", estimator="rls"),
    "asmc": SimOptions(controller="asmc"),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=DEFAULT)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    scenario = load_scenario(args.config)
    print(f"scenario {scenario.name}: ideal plant, exact measurements, best of {args.repeat}")
    for label, options in RUNS.items():
        best = None
        for _ in range(args.repeat):
            start = time.perf_counter()
            summary = simulate(scenario, options).summary
            wall = time.perf_counter() - start
            if best is None or wall < best[0]:
                best = (wall, summary)
        wall, summary = best
        step = summary["step_time_us"]
        print(
            f"{label:<20} {summary['duration_s']:4.1f} s simulated  "
            f"step median {step['median']:6.1f} us  p99 {step['p99']:6.1f} us  "
            f"wall {wall:5.2f} s"
        )


if __name__ == "__main__":
    main()

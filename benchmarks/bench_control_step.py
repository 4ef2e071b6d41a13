"""Cost of one control step, compiled and Python, and of the whole offline simulation.

For the paper scenario (10 s, ideal plant, exact measurements) and three runs --
passivity + paper estimator, passivity + RLS, and the adaptive sliding-mode controller
(eq. asc1, which always runs in Python) -- prints

- ``step``: :meth:`FlightControl.step <companion.control.flight.FlightControl.step>` alone
  (model terms, estimator, tilt reference, control law, trim, setpoint mapping), median
  and 99th percentile in microseconds, for the compiled step (the compiled twin of
  ``companion.control.control_step``) and the Python reference. The inputs (filtered
  state, desired state, applied force, dt) are recorded from one offline run and replayed
  cycle by cycle through a fresh ``FlightControl`` of each kind, so both paths time the
  same sequence;
- ``kernel``: the compiled twin's ``control_step.step`` alone (the step's arithmetic, the
  model's pieces included, without :class:`CompiledStep
  <companion.control.compiled_step.CompiledStep>`'s records around it), over the same
  recorded calls, the estimator on each cycle's own inputs (the paper scenario delays
  none);
- ``sim step``: the step as the offline simulator times it, which adds the state filter
  (feeding the measurements, reading q, q_dot, q_ddot; in Python on both paths);
- ``wall``: the whole 10 s run (control steps, truth plant at ``plant.rate_hz``, logging),
  best of ``--repeat``; the truth plant's own cost is printed by
  ``benchmarks/bench_plant.py``.

``--gap-ms G`` also times the compiled step over its first 1000 calls with a sleep of G ms
before each (the flight loop sleeps between poses, 8 ms at 125 Hz): what a step costs when
the core has been idle. On a 2-core VM the step of ``sitl_pickup.toml``
took 14-15 us back to back and 200-290 us after an 8 ms sleep (176 us with
``/dev/cpu_dma_latency`` held at 0): the wake-up, not the code, dominates the flight loop's
pose -> setpoint latency there.

``--cpu N`` pins the process to core N (``os.sched_setaffinity``); ``--scale F`` also
prints every figure multiplied by F, labelled as scaled, for a slower computer (a
Raspberry Pi 4 runs this Python 3-5 times slower than the development machine; nothing
here changes the clock). The CPU frequency is read from
``/sys/devices/system/cpu/cpu<N>/cpufreq`` when the machine exposes it and printed.
Targets: <= 20 us median per control step, <= 7 us for the kernel (goal 5 us),
<= 0.5 s wall for the 10 s run. ``--write`` also puts the figures in ``docs/step_speed.md``
with the machine and the commit.

Usage: ``python benchmarks/bench_control_step.py [--config configs/paper_sim.toml]
[--repeat 3] [--cpu 1] [--scale 4] [--write]``
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from checkout import written_by

from companion.control.compiled_step import skip_and_force
from companion.control.flight import FlightControl
from companion.estimation.estimator import Skip
from sitl.offline.simulation import SimOptions, SimResult, simulate
from sitl.scenario import Scenario, load_scenario

DEFAULT = Path(__file__).resolve().parent.parent / "configs" / "paper_sim.toml"
RUNS = {
    "passivity + paper": SimOptions(controller="passivity", estimator="paper"),
    "passivity + rls": SimOptions(controller="passivity", estimator="rls"),
    "asmc": SimOptions(controller="asmc"),
}


def record(scenario: Scenario, options: SimOptions) -> list[tuple]:
    """The (dt, state, desired, applied force) of every step of one run."""
    calls: list[tuple] = []
    step = FlightControl.step

    def recording(self, dt_s, state, desired, applied):
        kept = applied if isinstance(applied, Skip) else np.array(applied)
        calls.append((dt_s, state, desired, kept))
        return step(self, dt_s, state, desired, applied)

    FlightControl.step = recording  # type: ignore[method-assign]
    try:
        simulate(scenario, options)
    finally:
        FlightControl.step = step  # type: ignore[method-assign]
    return calls


def fresh_control(scenario: Scenario, options: SimOptions, compiled: bool) -> FlightControl:
    """The controller of ``options`` as the offline simulator builds it."""
    return FlightControl(
        scenario.beliefs,
        options.controller,
        rows=tuple(scenario.estimator.rows),
        actuated_rows=tuple(range(8)),
        estimator_kind=options.estimator or scenario.estimator.kind,
        compiled=compiled,
    )


def replay(
    scenario: Scenario, options: SimOptions, calls: list[tuple], compiled: bool, gap_s: float = 0.0
):
    """Microseconds per step of a fresh FlightControl over the recorded calls (None if
    this law has no compiled step), each after a sleep of ``gap_s`` [s] if positive."""
    control = fresh_control(scenario, options, compiled)
    if control.compiled != compiled:
        return None
    us = np.empty(len(calls))
    clock = time.perf_counter_ns
    step = control.step
    for i, (dt_s, state, desired, applied) in enumerate(calls):
        if gap_s > 0.0:
            time.sleep(gap_s)
        start = clock()
        step(dt_s, state, desired, applied)
        us[i] = (clock() - start) / 1e3
    return us


def replay_kernel(scenario: Scenario, options: SimOptions, calls: list[tuple]):
    """Microseconds per call of the compiled twin's ``step`` alone over the recorded calls
    (None if this law has no compiled step), with the buffer of a fresh FlightControl."""
    compiled = fresh_control(scenario, options, True)._compiled
    if compiled is None:
        return None
    kernel, work = compiled._module.step, compiled._work
    us = np.empty(len(calls))
    clock = time.perf_counter_ns
    for i, (dt_s, state, desired, applied) in enumerate(calls):
        skip, tau = skip_and_force(applied)
        args = (state.q, state.q_dot, state.q_ddot, desired.q, desired.q_dot, desired.q_ddot, tau)
        start = clock()
        kernel(work, dt_s, skip, *args)
        us[i] = (clock() - start) / 1e3
    return us


def best_run(scenario: Scenario, options: SimOptions, repeat: int) -> tuple[float, SimResult]:
    best: tuple[float, SimResult] | None = None
    for _ in range(repeat):
        start = time.perf_counter()
        result = simulate(scenario, options)
        wall = time.perf_counter() - start
        if best is None or wall < best[0]:
            best = (wall, result)
    assert best is not None
    return best


def cpu_frequency(cpu: int) -> str:
    base = Path(f"/sys/devices/system/cpu/cpu{cpu}/cpufreq")
    if not base.is_dir():
        return f"{base} absent: the clock cannot be read or lowered here"
    cur = (base / "scaling_cur_freq").read_text().strip()
    return f"cpu{cpu} at {int(cur) / 1e3:.0f} MHz ({base})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=DEFAULT)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--cpu", type=int, default=None, help="pin to this core")
    parser.add_argument("--scale", type=float, default=None, help="also print figures x F")
    parser.add_argument("--gap-ms", type=float, default=0.0, help="also time after G ms idle")
    parser.add_argument("--write", action="store_true", help="write docs/step_speed.md")
    args = parser.parse_args()
    rows: list[str] = []
    if args.cpu is not None:
        os.sched_setaffinity(0, {args.cpu})
        print(f"pinned to core {args.cpu}; {cpu_frequency(args.cpu)}")
    scenario = load_scenario(args.config)
    print(f"scenario {scenario.name}: ideal plant, exact measurements, best of {args.repeat}")

    def show(label: str, us: np.ndarray | None) -> str:
        if us is None:
            return f"{label} (Python only)"
        median, p99 = np.median(us), np.percentile(us, 99)
        text = f"{label} median {median:6.1f} p99 {p99:6.1f} us"
        if args.scale:
            text += f" [x{args.scale:g}: {median * args.scale:6.1f} / {p99 * args.scale:6.1f}]"
        return text

    for label, options in RUNS.items():
        calls = record(scenario, options)
        fast = replay(scenario, options, calls, compiled=True)
        slow = replay(scenario, options, calls, compiled=False)
        kernel = replay_kernel(scenario, options, calls)
        idle = (
            replay(scenario, options, calls[:1000], compiled=True, gap_s=args.gap_ms / 1e3)
            if args.gap_ms > 0.0
            else None
        )
        wall, result = best_run(scenario, options, args.repeat)
        sim = result.column("step_time_us")
        sim = sim[~np.isnan(sim)]
        walls = f"wall {wall:5.2f} s"
        if args.scale:
            walls += f" [x{args.scale:g}: {wall * args.scale:5.2f} s]"
        print(f"{label}:")
        print(f"  step  {show('compiled', fast)}   {show('python', slow)}")
        print(f"  {show('kernel', kernel)}")
        rows.append(
            f"| {label} | {cell(kernel)} | {cell(fast)} | {cell(slow)} | {cell(sim)} | {wall:.2f} |"
        )
        print(f"  {show('sim step (filter + step)', sim)}   {walls}")
        if args.gap_ms > 0.0 and fast is not None:
            print(f"  step  {show(f'compiled after {args.gap_ms:g} ms idle', idle)}")

    if args.write:
        text = page(scenario.name, args.repeat, rows)
        print(text)
        (Path(__file__).resolve().parent.parent / "docs" / "step_speed.md").write_text(text)


def cell(us: np.ndarray | None) -> str:
    """Median / 99th percentile [us], or a dash for a law without a compiled step."""
    if us is None:
        return "-"
    return f"{np.median(us):.1f} / {np.percentile(us, 99):.1f}"


def page(name: str, repeat: int, rows: list[str]) -> str:
    """docs/step_speed.md: the table, the machine and the commit."""
    return "\n".join(
        [
            "# The control step's speed",
            "",
            f"{written_by('bench_control_step.py --write')} Scenario {name}: ideal "
            "plant, exact measurements; the calls of one offline run replayed through a fresh "
            "controller of each kind. Microseconds, median / 99th percentile; on a shared "
            "or virtual machine they vary between runs by 10-20 %.",
            "",
            "- kernel: the compiled twin's `control_step.step` alone (the model's pieces "
            "through the capsule, the estimator, tilt reference, eq. tau2, trim, setpoint), "
            "target <= 7 us, goal <= 5 us;",
            "- step: `FlightControl.step` (the kernel and the records around it), compiled and "
            "Python (the numpy reference), target <= 20 us compiled;",
            "- sim step: the step with the state filter as the offline simulator times it;",
            f"- wall: the whole 10 s run, best of {repeat} [s], target <= 0.5 s.",
            "",
            "The model's M, C, G, Y beside Pinocchio: `benchmarks/bench_model.py` "
            "([model_speed.md](model_speed.md)).",
            "",
            "| run | kernel | step, compiled | step, Python | sim step | wall [s] |",
            "|---|---|---|---|---|---|",
            *rows,
            "",
        ]
    )


if __name__ == "__main__":
    main()

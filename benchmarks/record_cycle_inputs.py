"""Record the control cycle's inputs of a flight for ``companion check --timing``.

Flies the default virtual pickup (``sitl demo --clock virtual``: configs/sitl_pickup.toml,
seed 0, simulated time) and records, per control cycle, what the cycle hands its parts:
the state filter's calls (predict, pose, velocity, body rates, joints and their rates, in
the cycle's order), the battery voltage, and FlightControl.step's arguments (period,
desired state, applied force or why it is unknown). Keeps ``--cycles`` cycles from the
grasp on (the estimator running with the payload: the cycle's dearest part) and writes
them, as float32, to ``companion/mission/cycle_inputs.npz``
(:mod:`companion.mission.timing_check` reads it).

Usage: ``python benchmarks/record_cycle_inputs.py [--cycles 750] [--out PATH]``
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import numpy as np

from companion.control.flight import FlightControl
from companion.estimation.estimator import Skip
from companion.estimation.state import StateAssembler
from companion.mission.cycle import ControlCycle
from companion.mission.timing_check import RECORDING, SKIP_CODES
from sitl.demo_command import DemoCommand
from sitl.vehicle.options import RunOptions
from sitl.vehicle.virtual_flight import fly_virtual

NAN3, NAN2, NAN8 = [math.nan] * 3, [math.nan] * 2, [math.nan] * 8


def _blank() -> dict:
    return {
        "predict_dt_s": math.nan,
        "position_m": NAN3,
        "euler_rad": NAN3,
        "velocity_m_s": NAN3,
        "omega_rad_s": NAN3,
        "voltage_v": math.nan,
        "eta_rad": NAN2,
        "eta_dot_rad_s": NAN2,
        "joint_age_s": math.nan,
        "step_dt_s": math.nan,
        "qd": NAN8,
        "qd_dot": NAN8,
        "qd_ddot": NAN8,
        "applied": NAN8,
        "skip": 0,
        "phase": "",
    }


def record(cycles: int) -> dict[str, np.ndarray]:
    rows: list[dict] = []
    originals = {}

    def wrap(cls, name, keep):
        original = getattr(cls, name)
        originals.setdefault((cls, name), original)

        def recorded(self, *args, **kwargs):
            if rows:
                keep(rows[-1], *args, **kwargs)
            return original(self, *args, **kwargs)

        setattr(cls, name, recorded)

    run = ControlCycle.run

    def cycle_run(self, pose, received, received_cpu, received_process):
        rows.append(_blank())
        out = run(self, pose, received, received_cpu, received_process)
        rows[-1]["phase"] = self.mission.phase.value if self.offboard.flying else ""
        return out

    def keep_step(row, dt_s, state, desired, applied):
        row.update(step_dt_s=dt_s, qd=list(desired.q), qd_dot=list(desired.q_dot))
        row.update(qd_ddot=list(desired.q_ddot))
        if isinstance(applied, Skip):
            row["skip"] = SKIP_CODES.index(applied) + 1
        else:
            row["applied"] = list(np.asarray(applied, dtype=float))

    wrap(StateAssembler, "predict", lambda r, dt_s: r.update(predict_dt_s=dt_s))
    wrap(StateAssembler, "pose", lambda r, p, e, age_s=0.0: r.update(position_m=list(p)))
    wrap(StateAssembler, "pose", lambda r, p, e, age_s=0.0: r.update(euler_rad=list(e)))
    wrap(StateAssembler, "velocity", lambda r, v, age_s=0.0: r.update(velocity_m_s=list(v)))
    wrap(StateAssembler, "body_rates", lambda r, w, age_s=0.0: r.update(omega_rad_s=list(w)))
    wrap(StateAssembler, "joints", lambda r, eta, age_s=0.0: r.update(eta_rad=list(eta)))
    wrap(StateAssembler, "joints", lambda r, eta, age_s=0.0: r.update(joint_age_s=age_s))
    wrap(StateAssembler, "joint_rates", lambda r, d, age_s=0.0: r.update(eta_dot_rad_s=list(d)))
    wrap(FlightControl, "supply", lambda r, v: r.update(voltage_v=math.nan if v is None else v))
    wrap(FlightControl, "step", keep_step)
    ControlCycle.run = cycle_run  # type: ignore[method-assign]
    try:
        demo = DemoCommand(clock="virtual")
        scenario, plan, _ = demo.pickup()
        with tempfile.TemporaryDirectory() as tmp:
            options = RunOptions(seed=demo.seed, truth_log=None)
            fly_virtual(scenario, plan, Path(tmp) / "flight", options, figures=False, mcap=False)
    finally:
        ControlCycle.run = run  # type: ignore[method-assign]
        for (cls, name), original in originals.items():
            setattr(cls, name, original)
    start = next(i for i, r in enumerate(rows) if r["phase"] == "grasp")
    kept = rows[start : start + cycles]
    if len(kept) < cycles:
        raise SystemExit(f"only {len(kept)} cycles from the grasp on")
    arrays = {key: np.asarray([r[key] for r in kept]) for key in RECORDING if key != "skip"}
    out = {k: v.astype(np.float32) for k, v in arrays.items()}
    out["skip"] = np.asarray([r["skip"] for r in kept], dtype=np.int8)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=750)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    from companion.mission.timing_check import RECORDING_PATH

    path = args.out or RECORDING_PATH
    arrays = record(args.cycles)
    np.savez_compressed(path, **arrays)
    print(f"{path}: {args.cycles} cycles from the grasp on, {path.stat().st_size} bytes")


if __name__ == "__main__":
    main()

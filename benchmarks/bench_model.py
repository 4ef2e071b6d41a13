"""Benchmark: M, C, G and the regressor Y for one state, beside Pinocchio.

Prints median and p99 microseconds of
  - companion.model in one call: ManipulatorModel.evaluate(q, q_dot, theta, qr_dot,
    qr_ddot) -> (M, C, G, Y) (the generated C and both products in one extension call)
  - companion.model in three calls: terms(q, q_dot), then evaluate(theta) -> (M, C, G),
    then regressor(qr_dot, qr_ddot) -> Y
  - Pinocchio (same model, Translation -> RZ -> RY -> RX base): crba + computeCoriolisMatrix
    + computeGeneralizedGravity, in the same run
Targets: <= 20 us median for companion.model, <= 10 us for one call, and one call faster
than Pinocchio's three (which compute no regressor). ``--write`` also puts the figures in
``docs/model_speed.md`` with the machine and the commit.

Usage: python benchmarks/bench_model.py [--config configs/paper_sim.toml] [--n 20000]
[--write]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

from companion.model import ManipulatorModel
from sitl.scenario import load_scenario

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
from checkout import written_by  # noqa: E402
from pinocchio_reference import PERM, reference_model  # noqa: E402


def timed(fn, states, repeats: int = 1) -> np.ndarray:
    samples = np.empty(len(states))
    clock = time.perf_counter_ns
    for i, args in enumerate(states):
        start = clock()
        for _ in range(repeats):
            fn(*args)
        samples[i] = (clock() - start) / repeats / 1e3
    return samples


def report(name: str, us: np.ndarray, rows: list[str]) -> None:
    median, p99 = np.median(us), np.percentile(us, 99)
    print(f"{name:58s} median {median:7.2f} us   p99 {p99:7.2f} us")
    rows.append(f"| {name} | {median:.2f} | {p99:.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(ROOT / "configs" / "paper_sim.toml"))
    parser.add_argument("--n", type=int, default=20000, help="number of random states")
    parser.add_argument("--write", action="store_true", help="write docs/model_speed.md")
    args = parser.parse_args()
    rows: list[str] = []

    cfg = load_scenario(args.config)
    model = ManipulatorModel.from_config(cfg)
    theta = np.array(cfg.true_theta.as_tuple())
    rng = np.random.default_rng(0)
    states = [
        (rng.uniform(-1, 1, 8), rng.normal(size=8), rng.normal(size=8), rng.normal(size=8))
        for _ in range(args.n)
    ]

    def ours(q, q_dot, qr_dot, qr_ddot):
        terms = model.terms(q, q_dot)
        return terms.evaluate(theta), terms.regressor(qr_dot, qr_ddot)

    def ours_one_call(q, q_dot, qr_dot, qr_ddot):
        return model.evaluate(q, q_dot, theta, qr_dot, qr_ddot)

    def ours_terms(q, q_dot, qr_dot, qr_ddot):
        return model.terms(q, q_dot)

    ref = reference_model(cfg, tuple(theta))
    data = ref.createData()

    def pinocchio(q, q_dot, qr_dot, qr_ddot):
        qp, vp = q[PERM], q_dot[PERM]
        pin.crba(ref, data, qp)
        pin.computeCoriolisMatrix(ref, data, qp, vp)
        pin.computeGeneralizedGravity(ref, data, qp)

    for fn in (ours_one_call, ours, pinocchio):  # warm up caches and allocators
        timed(fn, states[:500])
    print(f"config {args.config}, {args.n} random states, one call per sample")
    report("companion.model: M, C, G, Y in one call (evaluate)", timed(ours_one_call, states), rows)
    report("companion.model: M, C, G, Y in three calls (pieces)", timed(ours, states), rows)
    report(
        "companion.model: terms() only (generated C + wrapping)", timed(ours_terms, states), rows
    )
    report("pinocchio: crba + computeCoriolisMatrix + gravity", timed(pinocchio, states), rows)
    if args.write:
        text = page(args.config, args.n, rows)
        print(text)
        (ROOT / "docs" / "model_speed.md").write_text(text)


def page(config: str, n: int, rows: list[str]) -> str:
    """docs/model_speed.md: the table, the machine and the commit."""
    return "\n".join(
        [
            "# M, C, G and Y beside Pinocchio",
            "",
            f"{written_by('bench_model.py --write')} Configuration "
            f"`{Path(config).name}`, {n} random states, one call per sample, in the same run; "
            "microseconds from Python, calls included. Pinocchio's three calls compute M, C "
            "and G on the same model (Translation, RZ, RY, RX base) and no regressor; its "
            "times include reordering q and q_dot into its joint order.",
            "",
            "| what | median [us] | p99 [us] |",
            "|---|---|---|",
            *rows,
            "",
        ]
    )


if __name__ == "__main__":
    main()

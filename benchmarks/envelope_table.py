"""Write docs/NAME.md from a finished campaign of configs/campaigns/NAME.toml (default
``envelope``; ``envelope_px4``, its sample with PX4 in the loop; ``envelope_px4_baseline``,
the adaptive controller paired with PX4's own position control on PX4): how each controller fared
over the envelope (outcomes, and p50 / p95 / max of each metric over the flights that
completed), the numbers the envelope's acceptance is judged on.

    sitl campaign configs/campaigns/envelope.toml --out OUT
    python benchmarks/envelope_table.py OUT --commit HASH [--machine TEXT] [--spec NAME]

``--commit`` is the commit the campaign flew (the results store records the package
version, not the commit); ``--machine`` what it flew on.
"""

from __future__ import annotations

import argparse
import sqlite3
import statistics
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from sitl.campaign.report import BASELINES, flown_by, paired_flights, percentile_rows
from sitl.campaign.spec import load_spec

ROOT = Path(__file__).resolve().parent.parent


def rows_of(out: Path) -> list[dict]:
    """Every row of the campaign's results table."""
    path = out / "results.sqlite"
    if not path.exists():
        sys.exit(f"{path}: no campaign results here")
    db = sqlite3.connect(path)
    db.row_factory = sqlite3.Row
    try:
        return [dict(r) for r in db.execute("SELECT * FROM flights")]
    finally:
        db.close()


def page(rows: list[dict], commit: str, machine: str, name: str) -> str:
    controllers = sorted({flown_by(r) for r in rows})
    spec_file = f"configs/campaigns/{name}.toml"
    spec = load_spec(ROOT / spec_file)
    lines = [
        f"# The flight envelope: `{spec_file}`",
        "",
        f"{spec.description}.",
        "",
        f"Written by `python benchmarks/envelope_table.py` from `sitl campaign "
        f"{spec_file}` flown at commit {commit} on {machine}: "
        f"{len(rows)} flights"
        + (
            ", each draw flown by every controller on the same seed."
            if len(controllers) > 1
            else "."
        )
        + (
            " With PX4 in the loop a flight's CPU time is the companion's process alone (PX4"
            " and the simulator run in their own)."
            if "px4" in spec.autopilots
            else ""
        ),
        "",
        "| controller | flights | outcomes |",
        "|---|---|---|",
    ]
    for controller in controllers:
        mine = [r for r in rows if flown_by(r) == controller]
        outcomes = Counter(
            r.get("outcome") or ("error" if r.get("status") == "error" else "?") for r in mine
        )
        text = ", ".join(f"{name} {n}" for name, n in outcomes.most_common())
        lines.append(f"| {controller} | {len(mine)} | {text} |")
    lines += [
        "",
        "Over the flights that completed:",
        "",
        "| controller | metric | n | p50 | p95 | max |",
        "|---|---|---|---|---|---|",
    ]
    for controller, label, n, p50, p95, high in percentile_rows(rows):
        label = label.replace("|", "\\|")  # |x| inside a table cell
        lines.append(f"| {controller} | {label} | {n} | {p50:.3g} | {p95:.3g} | {high:.3g} |")
    outside = [r for r in rows if spec.outside_bounds(r)]
    bounds = "; ".join(
        f"{c}: " + ", ".join(f"|{k}| <= {v:g}" for k, v in b.items())
        for c, b in spec.bounds.items()
    )
    lines += ["", f"Completed flights outside the spec's bounds ({bounds}): {len(outside)}."]
    for baseline in ("nonadaptive", "px4_position"):
        label = BASELINES[baseline][0]
        ratios = [
            adaptive["carry_rms_m"] / other["carry_rms_m"]
            for adaptive, other in paired_flights(rows, baseline)
            if all(r.get("completed") and r.get("carry_rms_m") for r in (adaptive, other))
        ]
        if ratios:
            half = sum(1 for x in ratios if x <= 0.5)
            lower = sum(1 for x in ratios if x < 1.0)
            lines.append(
                f"Paired carry RMS, adaptive over {label}, where both completed: {half} of "
                f"{len(ratios)} pairs at most 0.5, {lower} below 1 (median "
                f"{statistics.median(ratios):.2f})."
            )
    lines += _payload_figures(rows)
    starts = [r["finished_unix_s"] - r["wall_s"] for r in rows if r.get("wall_s") is not None]
    ends = [r["finished_unix_s"] for r in rows if r.get("finished_unix_s") is not None]
    if starts and ends:
        minutes = (max(ends) - min(starts)) / 60.0
        lines.append(f"Wall time, first flight's start to last flight's end: {minutes:.1f} min.")
    return "\n".join(lines) + "\n"


def _payload_figures(rows: list[dict]) -> list[str]:
    """The adaptive controller's payload estimate as the envelope's acceptance reads it:
    the CoM error against max(5 %, 3 mm), the reported standard deviation's coverage, the
    mass error by the battery's charge at take-off, and the flights' simulated length."""
    done = [r for r in rows if r["controller"] == "passivity" and r.get("completed")]
    if not done or any(r.get("com_m") is None for r in done):
        return []
    com = [abs(r["com_m"] - r["true_com_m"]) / max(0.05 * r["true_com_m"], 0.003) for r in done]
    out = ["", f"Adaptive, completed ({len(done)} flights):", ""]
    out.append(
        f"- p95 of |CoM error| / max(5 %, 3 mm): {float(np.percentile(com, 95)):.3g} "
        "(numpy's default percentile; at most 1 is within the bound)."
    )
    with_std = [r for r in done if r.get("mass_std_kg") is not None]
    if with_std:
        within = sum(
            1 for r in with_std if abs(r["mass_kg"] - r["true_mass_kg"]) <= 2 * r["mass_std_kg"]
        )
        stds = [1e3 * r["mass_std_kg"] for r in with_std]
        out.append(
            f"- The true payload mass within 2 reported standard deviations "
            f"(`payload_mass_std_kg`, the thrust scale's uncertainty in it): {within} of "
            f"{len(with_std)} ({100 * within / len(with_std):.0f} %); the standard deviation "
            f"{min(stds):.1f}-{max(stds):.1f} g, median {statistics.median(stds):.1f} g."
        )
    charge = "plant.battery.start_charge"
    if all(r.get(charge) is not None for r in done):
        parts = []
        for low, high in ((0.3, 0.5), (0.5, 0.75), (0.75, 1.0001)):
            bin_ = [abs(r["mass_error_pct"]) for r in done if low <= r[charge] < high]
            if bin_:
                parts.append(
                    f"{100 * low:.0f}-{min(100 * high, 100):.0f} %: p95 "
                    f"{float(np.percentile(bin_, 95)):.2f} % over {len(bin_)}"
                )
        out.append("- |mass error| by the battery's charge at take-off: " + "; ".join(parts) + ".")
    sim = [r["sim_s"] for r in done if r.get("sim_s") is not None]
    if sim:
        out.append(f"- Simulated flight time {min(sim):.0f}-{max(sim):.0f} s.")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="The campaign's --out directory.")
    parser.add_argument("--commit", required=True, help="The commit the campaign flew.")
    parser.add_argument("--machine", default="this machine", help="What it flew on.")
    parser.add_argument("--spec", default="envelope", help="The spec's name in configs/campaigns.")
    args = parser.parse_args()
    path = ROOT / "docs" / f"{args.spec}.md"
    path.write_text(page(rows_of(args.out), args.commit, args.machine, args.spec))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

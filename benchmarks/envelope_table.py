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
    starts = [r["finished_unix_s"] - r["wall_s"] for r in rows if r.get("wall_s") is not None]
    ends = [r["finished_unix_s"] for r in rows if r.get("finished_unix_s") is not None]
    if starts and ends:
        minutes = (max(ends) - min(starts)) / 60.0
        lines.append(f"Wall time, first flight's start to last flight's end: {minutes:.1f} min.")
    return "\n".join(lines) + "\n"


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

"""Write docs/fault_campaign.md from a finished run of configs/campaigns/faults.toml: the
fault x phase -> outcome table (safe of flown, and the outcomes), the flights that ended
unsafe by docs/faults.md's numbers with what they broke and their replay command, and the
touchdown speeds.

    sitl campaign configs/campaigns/faults.toml --out OUT
    python benchmarks/fault_table.py OUT --commit HASH [--machine TEXT]

``--commit`` is the commit the campaign flew (the results store records the package
version, not the commit); ``--machine`` what it flew on.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from envelope_table import rows_of

from sitl.campaign.report import fault_phase_table
from sitl.campaign.spec import load_spec

ROOT = Path(__file__).resolve().parent.parent
SPEC = "configs/campaigns/faults.toml"


def page(rows: list[dict], commit: str, machine: str) -> str:
    spec = load_spec(ROOT / SPEC)
    ok = [r for r in rows if r["status"] == "ok"]
    judged = [r for r in ok if r.get("fault_kind") not in (None, "none")]
    unsafe = [r for r in judged if not r.get("safe")]
    errors = len(rows) - len(ok)
    lines = [
        f"# Faults at every phase: `{SPEC}`",
        "",
        f"{spec.description}.",
        "",
        f"Written by `python benchmarks/fault_table.py` from `sitl campaign {SPEC}` flown at "
        f"commit {commit} on {machine}: {len(rows)} flights, {len(judged) - len(unsafe)} "
        f"ended safe by [faults.md](faults.md)'s numbers, {len(unsafe)} unsafe, {errors} "
        "crashed (errors).",
        "",
        "## Fault x phase -> outcome",
        "",
        "Each cell: the flights that ended safe of those flown (four payloads), and their "
        "outcomes with counts. `at a time` holds the faults given no phase (the object "
        "slipping after the grasp, the grasp failing).",
        "",
    ]
    phases, table = fault_phase_table(rows)
    lines.append("| fault | " + " | ".join(phases) + " |")
    lines.append("|---" * (len(phases) + 1) + "|")
    for label, cells in table:
        lines.append(f"| `{label}` | " + " | ".join(c.replace("|", "/") for c in cells) + " |")
    lines += ["", "## Unsafe flights", ""]
    if not unsafe:
        lines.append("None.")
    else:
        lines += [
            f"Each flies alone with `sitl campaign {SPEC} --out OUT --replay ID` (its log and "
            "figures in `OUT/replay/ID`).",
            "",
            "| fault | payload [kg @ m] | outcome | broken | ID |",
            "|---|---|---|---|---|",
        ]
        for r in sorted(unsafe, key=lambda r: str(r["fault"])):
            lines.append(
                f"| `{r['fault']}` | {r['payload.mass_kg']:g} @ {r['payload.position_m']:g} "
                f"| {r['outcome']} | {r['unsafe']} | `{r['flight_id']}` |"
            )
    touchdowns = [max(0.0, r["touchdown_m_s"]) for r in ok if r.get("touchdown_m_s") is not None]
    if touchdowns:
        lines += [
            "",
            f"Touchdown vertical speed over the flights: {min(touchdowns):.2f}-"
            f"{max(touchdowns):.2f} m/s (each flight's fastest touchdown; "
            "at most 1 m/s is safe).",
        ]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="The campaign's --out directory.")
    parser.add_argument("--commit", required=True, help="The commit the campaign flew.")
    parser.add_argument("--machine", default="this machine", help="What it flew on.")
    args = parser.parse_args()
    path = ROOT / "docs" / "fault_campaign.md"
    path.write_text(page(rows_of(args.out), args.commit, args.machine))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()

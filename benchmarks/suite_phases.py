"""How long the test command takes, phase by phase: the README's second line (which
``.ci/run`` runs) after its install, each check and pytest phase timed on its own.

    python benchmarks/suite_phases.py            # print the table
    python benchmarks/suite_phases.py --write    # and write docs/suite_time.md

Run it in the installed virtual environment, on an otherwise idle machine (the real-time
tests are timed as they run); ``PX4_SITL_DIR`` as ``.ci/run`` sets it, or the PX4 tests are
skipped (the table says so). Stops at the first phase that fails, as the command would.
Each pytest phase also reports its slowest tests (``PYTEST_ADDOPTS=--durations``, which
leaves the command as it is) and the tests that failed; every phase's whole output is kept
in ``--logs`` (a temporary directory by default, printed).
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from checkout import this_commit

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "suite_time.md"
CONTRACT_MIN = 20.0
"""The repository contract's bound on the whole command [min], on 2 cores."""
SLOWEST = 15
"""Slowest tests listed per pytest phase."""
_DURATION = re.compile(r"^\s*([0-9.]+)s (call|setup|teardown)\s+(\S+)")


def phases() -> list[str]:
    """The README's test command after its venv and install, split at ``&&``."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    line = next(row for row in text.splitlines() if 'pip install -e ".[test]"' in row)
    parts = [p.strip() for p in line.split("&&")]
    return [p for p in parts if not re.match(r"(python3 -m venv|\. \.venv|pip install)", p)]


def run(command: str, log: Path) -> tuple[int, float, list[str]]:
    """Run one phase from the repository's root, its output kept in ``log``; its status,
    wall time [s] and output lines."""
    env = dict(os.environ)
    if command.startswith("pytest"):
        env["PYTEST_ADDOPTS"] = f"{env.get('PYTEST_ADDOPTS', '')} --durations={SLOWEST}".strip()
    start = time.perf_counter()
    done = subprocess.run(shlex.split(command), cwd=ROOT, capture_output=True, text=True, env=env)
    wall_s = time.perf_counter() - start
    log.write_text(done.stdout + done.stderr, encoding="utf-8")
    lines = [row for row in (done.stdout + done.stderr).splitlines() if row.strip()]
    return done.returncode, wall_s, lines


def slowest(lines: list[str]) -> list[tuple[float, str]]:
    """(seconds, test) of the phase's slowest setups, calls and teardowns, as pytest's
    ``--durations`` lists them (a module's shared flight shows as a setup)."""
    out = []
    for row in lines:
        match = _DURATION.match(row)
        if match:
            out.append((float(match.group(1)), f"{match.group(3)} ({match.group(2)})"))
    return sorted(out, reverse=True)[:SLOWEST]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="write docs/suite_time.md")
    parser.add_argument("--logs", type=Path, help="keep each phase's output here")
    args = parser.parse_args()
    logs = args.logs or Path(tempfile.mkdtemp(prefix="suite-phases-"))
    logs.mkdir(parents=True, exist_ok=True)
    rows, total_s, failed, details = [], 0.0, False, []
    for number, command in enumerate(phases(), 1):
        status, wall_s, lines = run(command, logs / f"phase{number}.log")
        last = lines[-1].strip("= ") if lines else ""
        total_s += wall_s
        rows.append((command, status, wall_s, last))
        print(f"{wall_s:7.1f} s  status {status}  {command}  ({last})", flush=True)
        if command.startswith("pytest"):
            failures = [row for row in lines if row.startswith(("FAILED ", "ERROR "))]
            details += [f"`{command}`: the slowest", ""]
            details += [f"- {s:.0f} s {test}" for s, test in slowest(lines)]
            details += [f"- {row}" for row in failures]
            details.append("")
        if status != 0:
            failed = True
            break
    print(f"each phase's output: {logs}")
    px4 = os.environ.get("PX4_SITL_DIR") or "unset: the PX4 tests skipped"
    load = os.getloadavg()[0]
    lines = [
        "# How long the test command takes",
        "",
        f"Written by `benchmarks/suite_phases.py` on {platform.node()} ({os.cpu_count()} "
        f"cores, load average {load:.2f} at the end, Python {platform.python_version()}), "
        f"commit {this_commit()}, `PX4_SITL_DIR` {px4}. The README's test command after its "
        "install, phase by phase.",
        "",
        "| phase | status | wall [s] | last line |",
        "|---|---|---|---|",
        *(f"| `{c}` | {s} | {w:.0f} | {last} |" for c, s, w, last in rows),
        "",
        f"All phases: {total_s / 60:.1f} min"
        + (" (stopped at the failed phase)" if failed else "")
        + f", against the contract's {CONTRACT_MIN:g} min for the whole command (the install "
        "not included here).",
        "",
        "## Where the time goes",
        "",
        *details,
    ]
    print("\n".join(lines))
    if args.write:
        DOC.write_text("\n".join(lines), encoding="utf-8")
        print(f"wrote {DOC.relative_to(ROOT)}")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()

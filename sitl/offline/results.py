"""Writing simulation results: summary.json, timeseries.csv and the comparison table."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sitl.offline.simulation import COLUMNS, SimResult

__all__ = ["comparison_markdown", "write_summary", "write_timeseries"]


def write_summary(summary: dict, path: Path) -> Path:
    """summary.json (NaN and infinity written as null, so any JSON reader opens it)."""

    def clean(value):
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items()}
        if isinstance(value, list | tuple):
            return [clean(v) for v in value]
        if isinstance(value, float) and not math.isfinite(value):
            return None
        return value

    path.write_text(json.dumps(clean(summary), indent=2) + "\n")
    return path


def write_timeseries(result: SimResult, path: Path, rate_hz: float = 100.0) -> Path:
    """timeseries.csv at most ``rate_hz`` rows per simulated second (all columns of
    ``sitl.offline.COLUMNS``; empty cells for values that do not exist)."""
    t = result.column("t_s")
    dt = float(t[1] - t[0]) if t.size > 1 else 1.0
    stride = max(1, round(1.0 / (rate_hz * dt)))
    rows = result.data[::stride]
    with path.open("w") as f:
        f.write(",".join(COLUMNS) + "\n")
        for row in rows:
            f.write(",".join("" if np.isnan(v) else repr(float(v)) for v in row) + "\n")
    return path


def _pct(value: float | None) -> str:
    return "n/a" if value is None else f"{value:+.1f} %"


def _time(value: float | None) -> str:
    return "never" if value is None else f"{value:.2f} s"


def comparison_markdown(runs: Sequence[tuple[str, dict]]) -> str:
    """A markdown table of the runs' summaries (name, summary)."""
    lines = [
        "| run | m2 error | lc error | m2 settles (5 %) | lc settles (5 %) "
        "| RMS position error | max position error | RMS joint error | step median / p99 |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in runs:
        if s["controller"] == "nonadaptive":
            name += " (estimator runs alongside, unused by the law)"
        estimated = s.get("estimated_parameters", ["m2", "m3", "m4"])
        lc_err = _pct(s["errors_pct"]["lc"]) if "m3" in estimated else "not estimated"
        lc_settle = _time(s["settle_time_s"]["lc"]) if "m3" in estimated else "n/a"
        lines.append(
            f"| {name} | {_pct(s['errors_pct']['m2'])} | {lc_err} "
            f"| {_time(s['settle_time_s']['m2'])} | {lc_settle} "
            f"| {s['rms_position_error_m'] * 100:.1f} cm "
            f"| {s['max_position_error_m'] * 100:.1f} cm "
            f"| {s['rms_joint_error_rad']:.3f} rad "
            f"| {s['step_time_us']['median']:.0f} / {s['step_time_us']['p99']:.0f} us |"
        )
    return "\n".join(lines) + "\n"

"""A campaign's report, computed from its results table alone: ``report.html``, one file
that opens offline (its figures embedded as base64 PNGs), and the PNGs beside it.

It shows the envelope maps (the mass and centre-of-mass errors of the payload estimate
over the payload's mass and its point on link 2), each bounded figure against every axis
of the campaign (with the bound and the flights that did not complete), a percentile
table (p50, p95, max of each figure, per controller and autopilot: :func:`flown_by`), the
paired comparison of the adaptive controller against each baseline flown beside it (the
non-adaptive law, PX4's own position control, ASMC: the same draws, seeds and faults), and
every flight that did not complete with the command that replays it alone; with the spec's
bounds, every completed flight outside them, with its replay command too.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sitl.campaign.spec import CampaignSpec
from sitl.campaign.store import failed, refused
from sitl.vehicle.mission_phases import FAULT_PHASES

__all__ = [
    "BASELINES",
    "METRICS",
    "REPORT_FILES",
    "fault_phase_table",
    "flown_by",
    "paired_flights",
    "percentile_rows",
    "write_report",
]

Row = dict[str, Any]

REPORT_FILES = ("report.html",)
METRICS: tuple[tuple[str, str, Callable[[float], float]], ...] = (
    ("mass_error_pct", "|mass error| [%]", abs),
    ("com_error_pct", "|CoM error| [%]", abs),
    ("placement_error_m", "placement error [cm]", lambda v: 100.0 * v),
    ("carry_rms_m", "carry RMS [cm]", lambda v: 100.0 * v),
    ("carry_max_error_m", "carry max error [cm]", lambda v: 100.0 * v),
    ("max_tilt_deg", "max tilt [deg]", lambda v: v),
    ("late_cycles", "late cycles", lambda v: v),
    ("cpu_s", "CPU per flight [s]", lambda v: v),
)
"""Figures of the percentile table: column, label, conversion."""

MASS, COM = "payload.mass_kg", "payload.position_m"


def _values(rows: Sequence[Row], column: str, convert: Callable[[float], float]) -> np.ndarray:
    return np.array(
        [convert(float(r[column])) for r in rows if r.get(column) is not None], dtype=np.float64
    )


def flown_by(row: Row) -> str:
    """Who flew a row's flight: its controller, with `` on px4`` when the real PX4 flew it
    (the imitation's flights are named by the controller alone)."""
    autopilot = row.get("autopilot") or "imitation"
    return row["controller"] if autopilot == "imitation" else f"{row['controller']} on {autopilot}"


def percentile_rows(rows: Sequence[Row]) -> list[tuple[str, str, int, float, float, float]]:
    """(controller, metric label, n, p50, p95, max) for each controller (and autopilot,
    :func:`flown_by`) and metric, over the flights that completed (the estimate and carry
    of a flight that did not are not the controller's)."""
    table = []
    for controller in sorted({flown_by(r) for r in rows}):
        done = [r for r in rows if flown_by(r) == controller and r.get("completed")]
        for column, label, convert in METRICS:
            v = _values(done, column, convert)
            if v.size:
                p50, p95 = np.percentile(v, [50, 95])
                table.append(
                    (controller, label, int(v.size), float(p50), float(p95), float(v.max()))
                )
    return table


def _png(fig: Any, out_dir: Path, name: str) -> str:
    """Save ``fig`` as OUT/NAME.png and return it as a data URI."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110, bbox_inches="tight")
    data = buffer.getvalue()
    (out_dir / f"{name}.png").write_bytes(data)
    return "data:image/png;base64," + base64.b64encode(data).decode()


def _envelope(rows: Sequence[Row], axes: Sequence[str], out_dir: Path, plt: Any) -> str | None:
    if MASS not in axes:
        return None
    adaptive = [r for r in rows if r["controller"] == "passivity" and r["status"] == "ok"]
    fig, panels = plt.subplots(1, 2, figsize=(11, 4.2), layout="constrained")
    for ax, column, label in (
        (panels[0], "mass_error_pct", "mass error [%]"),
        (panels[1], "com_error_pct", "CoM error [%]"),
    ):
        have = [r for r in adaptive if r.get(column) is not None]
        x = [r[MASS] for r in have]
        c = np.array([r[column] for r in have], dtype=np.float64)
        if COM in axes:
            limit = max(5.0, float(np.max(np.abs(c)))) if c.size else 5.0
            y = [r[COM] for r in have]
            points = ax.scatter(x, y, c=c, cmap="coolwarm", vmin=-limit, vmax=limit, s=28)
            fig.colorbar(points, ax=ax, label=label)
        else:
            ax.scatter(x, c, s=28)
            ax.axhline(0.0, color="k", lw=0.8)
        ax.set_xlabel("payload mass [kg]")
        ax.set_ylabel("payload point along link 2 [m]" if COM in axes else label)
        ax.set_title(f"passivity: {label} of the estimate")
        ax.grid(alpha=0.3)
    uri = _png(fig, out_dir, "envelope")
    plt.close(fig)
    return uri


AXIS_FIGURES: tuple[tuple[str, str, float], ...] = (
    ("mass_error_pct", "mass error [%]", 1.0),
    ("com_error_pct", "CoM error [%]", 1.0),
    ("placement_error_m", "placement error [cm]", 100.0),
    ("carry_rms_m", "carry RMS [cm]", 100.0),
)
"""The figures drawn against every axis (:func:`_by_axis`): column, label, scale to it."""


def _by_axis(
    rows: Sequence[Row],
    axes: Sequence[str],
    spec: CampaignSpec | None,
    out_dir: Path,
    plt: Any,
) -> list[tuple[str, str]]:
    """For each of :data:`AXIS_FIGURES`, one figure: that figure of every completed flight
    (one colour per controller) against each axis of the campaign, the spec's bound drawn
    where it has one, and the flights that did not complete marked on the axis (so that a
    regression along one axis shows at a glance). Returns (label, data URI) pairs."""
    numeric = [a for a in axes if any(isinstance(r.get(a), int | float) for r in rows)]
    if not numeric:
        return []
    controllers = sorted({flown_by(r) for r in rows})
    colours = dict(
        zip(controllers, ("tab:blue", "tab:orange", "tab:green", "tab:purple"), strict=False)
    )
    bounds: dict[str, float] = {}
    if spec is not None:
        bounds.update(spec.bounds.get("passivity", {}).items())
    columns = min(len(numeric), 5)
    lines = math.ceil(len(numeric) / columns)
    figures = []
    for column, label, scale in AXIS_FIGURES:
        if not any(r.get(column) is not None for r in rows):
            continue
        fig, panels = plt.subplots(
            lines, columns, figsize=(2.9 * columns, 2.4 * lines), layout="constrained",
            squeeze=False,
        )  # fmt: skip
        for ax, axis in zip(panels.flat, numeric, strict=False):
            for controller in controllers:
                mine = [r for r in rows if flown_by(r) == controller]
                done = [r for r in mine if r.get("completed") and r.get(column) is not None]
                ax.scatter(
                    [r[axis] for r in done], [scale * float(r[column]) for r in done],
                    s=9, c=colours.get(controller, "k"), label=controller,
                )  # fmt: skip
                missed = [r for r in mine if not r.get("completed") and r.get(axis) is not None]
                if missed:
                    ax.scatter(
                        [r[axis] for r in missed], [0.0] * len(missed), marker="x", s=22,
                        c="tab:red", label=f"{controller}: not completed",
                    )  # fmt: skip
            bound = bounds.get(column)
            if bound is not None:
                for sign in (1.0, -1.0) if column.endswith("_pct") else (1.0,):
                    ax.axhline(sign * scale * bound, color="k", lw=0.8, ls="--")
            ax.set_xlabel(axis, fontsize=7)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
        for ax in panels.flat[len(numeric) :]:
            ax.set_visible(False)
        panels.flat[0].set_ylabel(label, fontsize=8)
        panels.flat[0].legend(fontsize=6, loc="best")
        fig.suptitle(f"{label} against each axis (dashed: the bound)", fontsize=9)
        figures.append((label, _png(fig, out_dir, f"by_axis_{column}")))
        plt.close(fig)
    return figures


BASELINES = {
    "nonadaptive": ("non-adaptive", "paired"),
    "px4_position": ("PX4 position control", "paired_px4_position"),
    "asmc": ("ASMC", "paired_asmc"),
}
"""The baselines the adaptive controller is paired with: label, PNG name."""


def paired_flights(rows: Sequence[Row], baseline: str) -> list[tuple[Row, Row]]:
    """(passivity, ``baseline``) flights of the same draw, seed, fault and autopilot."""
    by_pair: dict[str, dict[str, Row]] = {}
    for r in rows:
        by_pair.setdefault(r["pair_id"], {})[r["controller"]] = r
    return [
        (p["passivity"], p[baseline])
        for p in by_pair.values()
        if "passivity" in p and baseline in p
    ]


def _paired(
    pairs: list[tuple[Row, Row]], baseline: str, out_dir: Path, plt: Any
) -> tuple[str | None, str]:
    label, png = BASELINES[baseline]
    lines = ["<table><tr><th>figure</th><th>pairs</th><th>passivity median</th>"
             f"<th>{html.escape(label)} median</th><th>passivity lower in</th></tr>"]  # fmt: skip
    completed = [(int(bool(a.get("completed"))), int(bool(b.get("completed")))) for a, b in pairs]
    lines.append(
        f"<tr><td>completed</td><td>{len(pairs)}</td>"
        f"<td>{sum(a for a, _ in completed)}</td><td>{sum(b for _, b in completed)}</td>"
        "<td></td></tr>"
    )
    for column, metric, convert in METRICS[2:5]:
        both = [
            (convert(float(a[column])), convert(float(b[column])))
            for a, b in pairs
            if a.get(column) is not None and b.get(column) is not None
        ]
        if not both:
            continue
        arr = np.array(both)
        lower = float(np.mean(arr[:, 0] < arr[:, 1]))
        half = float(np.mean(arr[:, 0] <= 0.5 * arr[:, 1]))
        lines.append(
            f"<tr><td>{html.escape(metric)}</td><td>{len(both)}</td>"
            f"<td>{np.median(arr[:, 0]):.2f}</td><td>{np.median(arr[:, 1]):.2f}</td>"
            f"<td>{100 * lower:.0f} % (at most half in {100 * half:.0f} %)</td></tr>"
        )
    lines.append("</table>")
    both = [
        (100 * a["carry_rms_m"], 100 * b["carry_rms_m"])
        for a, b in pairs
        if a.get("carry_rms_m") is not None and b.get("carry_rms_m") is not None
    ]
    if not both:
        return None, "\n".join(lines)
    arr = np.array(both)
    fig, ax = plt.subplots(figsize=(5, 4.5), layout="constrained")
    ax.scatter(arr[:, 1], arr[:, 0], s=25)
    top = float(arr.max()) * 1.1
    ax.plot([0, top], [0, top], "k--", lw=1, label="equal")
    ax.plot([0, top], [0, top / 2], "k:", lw=1, label="half")
    ax.set_xlabel(f"{label} carry RMS [cm]")
    ax.set_ylabel("passivity (adaptive) carry RMS [cm]")
    ax.set_title("paired flights: same draw, seed and fault")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    uri = _png(fig, out_dir, png)
    plt.close(fig)
    return uri, "\n".join(lines)


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return html.escape(str(value))


def _flight_table(flights: Sequence[tuple[Row, str]], axes: Sequence[str], what: str) -> str:
    """A table of flights, each with its identity, axis values, the ``what`` column (its
    HTML cell content, already escaped) and its replay command."""
    lines = [
        "<table><tr><th>flight</th><th>controller</th><th>fault</th><th>seed</th>"
        + "".join(f"<th>{html.escape(a)}</th>" for a in axes)
        + f"<th>{html.escape(what)}</th><th>replay</th></tr>",
    ]
    for r, detail in flights:
        lines.append(
            f"<tr><td><code>{r['flight_id']}</code></td><td>{_fmt(flown_by(r))}</td>"
            f"<td>{_fmt(r['fault'])}</td><td>{r['seed']}</td>"
            + "".join(f"<td>{_fmt(r.get(a))}</td>" for a in axes)
            + f"<td>{detail}</td><td><code>{html.escape(r.get('replay') or '')}</code></td></tr>"
        )
    lines.append("</table>")
    return "\n".join(lines)


def _refused(rows: Sequence[Row], axes: Sequence[str]) -> str:
    mine = [r for r in rows if refused(r)]
    if not mine:
        return "<p>No payload was refused.</p>"
    flights = [(r, html.escape(str(r.get("failure") or ""))) for r in mine]
    return (
        f"<p>{len(mine)} of {len(rows)} flights were refused in the grasp or the lift's first "
        "centimetres: the payload needed more hover thrust or servo torque than the flight "
        "config allows; the gripper let go where the object lay and the vehicle flew home.</p>\n"
        + _flight_table(flights, axes, "outcome")
    )


def _failed(rows: Sequence[Row], axes: Sequence[str]) -> str:
    not_completed = [r for r in rows if failed(r)]
    if not not_completed:
        return "<p>Every flight completed or was refused.</p>"
    flights = []
    for r in not_completed:
        if r["status"] == "error":
            last = (r.get("error") or "").strip().splitlines()
            what = "error: " + (last[-1] if last else "")
            trace = html.escape(r.get("error") or "")
            detail = f"<details><summary>{html.escape(what)}</summary><pre>{trace}</pre></details>"
        else:
            detail = html.escape(f"{r.get('outcome')}: {r.get('failure') or ''}")
        flights.append((r, detail))
    return (
        f"<p>{len(not_completed)} of {len(rows)} flights did not complete (faults injected on "
        "purpose included). Each command flies the flight alone, with its log and figures.</p>\n"
        + _flight_table(flights, axes, "outcome")
    )


def fault_phase_table(rows: Sequence[Row]) -> tuple[list[str], list[tuple[str, list[str]]]]:
    """The fault x phase -> outcome table of the flights given a fault: (the phases, in
    flight order, with ``at a time`` for faults given a time or none; per fault (its label
    without the phase) one cell per phase: ``safe/flown`` and the outcomes with their
    counts, empty where nothing was flown)."""
    faulty = [r for r in rows if r.get("status") == "ok" and _given_fault(r)]
    phases = [p for p in FAULT_PHASES if any(r.get("fault_phase") == p for r in faulty)]
    if any(r.get("fault_phase") is None for r in faulty):
        phases.append("at a time")
    cells: dict[str, dict[str, list[Row]]] = {}
    for r in faulty:
        label = _without_phase(str(r["fault"]))
        cells.setdefault(label, {}).setdefault(r.get("fault_phase") or "at a time", []).append(r)
    table = []
    for label in sorted(cells):
        line = []
        for phase in phases:
            flown = cells[label].get(phase, [])
            if not flown:
                line.append("")
                continue
            outcomes = Counter(str(r.get("outcome")) for r in flown)
            safe = sum(1 for r in flown if r.get("safe"))
            text = ", ".join(f"{o} {n}" for o, n in sorted(outcomes.items()))
            line.append(f"{safe}/{len(flown)} safe: {text}")
        table.append((label, line))
    return phases, table


def _given_fault(row: Row) -> bool:
    """The flight was given a fault (rows written before faults had a kind column have
    none: they are left out)."""
    return row.get("fault_kind") not in (None, "none")


def _without_phase(label: str) -> str:
    """A fault's label without its ``at_phase`` and ``offset_s`` values."""
    kind, _, values = label.partition("(")
    kept = [
        v for v in values.rstrip(")").split(", ")
        if v and not v.startswith(("at_phase=", "offset_s="))
    ]  # fmt: skip
    return f"{kind}({', '.join(kept)})" if kept else kind


def _faults(rows: Sequence[Row], axes: Sequence[str]) -> str:
    phases, table = fault_phase_table(rows)
    if not table:
        return "<p>No flight was given a fault.</p>"
    judged = [r for r in rows if r.get("status") == "ok" and _given_fault(r)]
    unsafe = [(r, html.escape(str(r.get("unsafe") or ""))) for r in judged if not r.get("safe")]
    lines = [
        f"<p>{len(judged) - len(unsafe)} of {len(judged)} flights given a fault ended safe by "
        "docs/faults.md's numbers. Each cell: safe of flown, and the outcomes.</p>",
        "<table><tr><th>fault</th>" + "".join(f"<th>{html.escape(p)}</th>" for p in phases)
        + "</tr>",
    ]  # fmt: skip
    for label, line in table:
        lines.append(
            f"<tr><td>{html.escape(label)}</td>"
            + "".join(f"<td>{html.escape(c)}</td>" for c in line)
            + "</tr>"
        )
    lines.append("</table>")
    if unsafe:
        lines += [
            f"<p>{len(unsafe)} flights ended unsafe:</p>",
            _flight_table(unsafe, axes, "unsafe"),
        ]
    return "\n".join(lines)


_STYLE = """
body { font-family: sans-serif; margin: 2em; max-width: 1200px; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; display: block;
        max-width: 100%; overflow-x: auto; }
th, td { border: 1px solid #bbb; padding: 3px 8px; text-align: right; vertical-align: top; }
th { background: #eee; }
code { font-size: 0.85em; word-break: break-all; }
td:last-child { text-align: left; }
img { max-width: 100%; }
"""


def _outside(rows: Sequence[Row], axes: Sequence[str], spec: CampaignSpec) -> str:
    broken = [(r, spec.outside_bounds(r)) for r in rows]
    flights = [(r, html.escape("; ".join(what))) for r, what in broken if what]
    limits = "; ".join(
        f"{c}: " + ", ".join(f"|{k}| <= {v:g}" for k, v in b.items())
        for c, b in spec.bounds.items()
    )
    if not flights:
        return f"<p>Every completed flight lies within the bounds ({html.escape(limits)}).</p>"
    return (
        f"<p>{len(flights)} of {len(rows)} flights completed outside the bounds "
        f"({html.escape(limits)}). Each command flies the flight alone.</p>\n"
        + _flight_table(flights, axes, "outside")
    )


def write_report(
    rows: Sequence[Row],
    axes: Sequence[str],
    out_dir: Path,
    title: str,
    description: str = "",
    spec: CampaignSpec | None = None,
) -> Path:
    """Write ``OUT/report.html`` and its PNGs from the results ``rows`` (with ``spec``'s
    bounds, the flights outside them); returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in rows if r["status"] == "ok"]
    errors = len(rows) - len(ok)
    done = sum(1 for r in ok if r.get("completed"))
    refusals = sum(1 for r in ok if refused(r))
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>Campaign {html.escape(title)}</h1>",
        f"<p>{html.escape(description)}</p>" if description else "",
        f"<p>{len(rows)} flights: {done} completed, {refusals} refused (beyond authority), "
        f"{len(ok) - done - refusals} flown without completing, "
        f"{errors} crashed (errors). Versions: "
        f"{html.escape(', '.join(sorted({str(r.get('version')) for r in rows})))}.</p>",
    ]
    by_controller = sorted({flown_by(r) for r in rows})
    parts.append(
        "<table><tr><th>controller</th><th>flights</th><th>completed</th><th>rate</th></tr>"
    )
    for c in by_controller:
        mine = [r for r in rows if flown_by(r) == c]
        n_done = sum(1 for r in mine if r.get("completed"))
        rate = n_done / len(mine) if mine else math.nan
        parts.append(
            f"<tr><td>{c}</td><td>{len(mine)}</td><td>{n_done}</td><td>{100 * rate:.1f} %</td></tr>"
        )
    parts.append("</table>")
    envelope = _envelope(rows, axes, out_dir, plt)
    if envelope:
        parts += ["<h2>Envelope: the payload estimate</h2>", f"<img src='{envelope}'>"]
    for label, uri in _by_axis(rows, axes, spec, out_dir, plt):
        parts += [f"<h2>{html.escape(label)} against each axis</h2>", f"<img src='{uri}'>"]
    parts.append("<h2>Percentiles (completed flights)</h2>")
    parts.append(
        "<table><tr><th>controller</th><th>figure</th><th>n</th><th>p50</th><th>p95</th><th>max</th></tr>"
    )
    for controller, label, n, p50, p95, top in percentile_rows(rows):
        parts.append(
            f"<tr><td>{controller}</td><td>{html.escape(label)}</td><td>{n}</td>"
            f"<td>{p50:.3g}</td><td>{p95:.3g}</td><td>{top:.3g}</td></tr>"
        )
    parts.append("</table>")
    paired = [(b, pairs) for b in BASELINES if (pairs := paired_flights(ok, b))]
    if not paired:
        parts += ["<h2>Paired flights</h2>", "<p>No paired flights (the spec flies one "
                  "controller).</p>"]  # fmt: skip
    for baseline, pairs in paired:
        parts.append(f"<h2>Adaptive (passivity) against {BASELINES[baseline][0]}, paired</h2>")
        paired_png, paired_table = _paired(pairs, baseline, out_dir, plt)
        parts.append(paired_table)
        if paired_png:
            parts.append(f"<img src='{paired_png}'>")
    parts += ["<h2>Faults by phase: safe or not</h2>", _faults(rows, axes)]
    parts += ["<h2>Flights that did not complete</h2>", _failed(rows, axes)]
    parts += ["<h2>Payloads refused (beyond authority)</h2>", _refused(rows, axes)]
    if spec is not None and spec.bounds:
        parts += ["<h2>Flights outside the bounds</h2>", _outside(rows, axes, spec)]
    parts.append("</body></html>")
    path = out_dir / "report.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path

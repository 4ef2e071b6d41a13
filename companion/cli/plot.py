"""``companion plot LOG --out DIR``: tracking, estimation and arm figures of a flight log.

Reads a log written by :class:`companion.logs.flightlog.FlightLogWriter` and draws, with
matplotlib's non-interactive Agg backend (files only):

- ``tracking.png``: x, y, z against the desired trajectory, roll and pitch against the
  attitude setpoint, and the horizontal path; PX4 mode changes as dotted lines;
- ``estimation.png``: m2 and lc estimates (shaded where the estimator is confident), its
  excitation and spread; beside the estimate the truth, where one is known (a simulator's
  flight: :class:`TruthLines`);
- ``arm.png``: joint angles (filtered, desired, read from the servos) and joint torques
  (commanded and measured from present current).

A missing or malformed log prints one ``error:`` line and exits with status 2; a log
whose last line was cut (a crash, a power cut) is drawn up to its last whole row, with a
``warning:`` line. Figures are never overwritten: an ``--out`` that already holds them
gets its figures in ``OUT-2``, ``OUT-3``, ... (:func:`companion.cli.usage.output_dir_or_exit`).
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from companion.cli.usage import fail, output_dir_or_exit
from companion.logs.flightlog import FlightLog, FlightLogError, read_flight_log

__all__ = ["FIGURES", "TruthLines", "figures_available", "plot", "plot_flight_log"]

FIGURES = ("tracking.png", "estimation.png", "arm.png")
"""The figures :func:`plot_flight_log` writes."""


@dataclass(frozen=True)
class TruthLines:
    """The true m2 [kg] and lc [m] of link 2 over vehicle time ``t_s`` [s] (arrays of one
    length), drawn beside the estimate: what a simulator knows and the companion never
    sees."""

    t_s: np.ndarray
    m2_kg: np.ndarray
    lc_m: np.ndarray


def finite_only(flight: FlightLog) -> tuple[FlightLog, list[str]]:
    """``flight`` with its infinite numbers (``1e999`` in the file) as NaN, drawn as gaps
    like empty cells, and a line naming the columns that held them (none: no line)."""
    columns = dict(flight.columns)
    infinite: list[str] = []
    for name, values in columns.items():
        if values.dtype.kind == "f" and np.isinf(values).any():
            infinite.append(f"{name} ({int(np.isinf(values).sum())})")
            columns[name] = np.where(np.isinf(values), np.nan, values)
    notes = []
    if infinite:
        notes.append(f"infinite values drawn as gaps: {', '.join(infinite)}")
    return replace(flight, columns=columns), notes


DRAWN_COLUMNS = (
    *("q_x_m", "q_y_m", "q_z_m", "qd_x_m", "qd_y_m", "qd_z_m", "q_phi_rad", "q_theta_rad"),
    *("sp_roll_rad", "sp_pitch_rad", "theta_hat_m2_kg", "theta_hat_lc_m"),
    *("theta_excitation", "theta_spread", "q_eta1_rad", "q_eta2_rad"),
    *("qd_eta1_rad", "qd_eta2_rad", "servo_pos_eta1_rad", "servo_pos_eta2_rad"),
    *("servo_tau_cmd_eta1_n_m", "servo_tau_cmd_eta2_n_m"),
    *("servo_tau_meas_eta1_n_m", "servo_tau_meas_eta2_n_m"),
)
"""The flight log's columns the figures draw (against ``t_vehicle_s``)."""


def figures_available() -> bool:
    """Whether matplotlib is installed (the ``plot`` extra; not in the flight install)."""
    return importlib.util.find_spec("matplotlib") is not None


def _mode_lines(ax, flight: FlightLog, t0: float) -> None:
    ev = flight.events
    for t, kind, detail in zip(ev["t_vehicle_s"], ev["kind"], ev["detail"], strict=True):
        if kind == "mode":
            ax.axvline(t - t0, color="0.6", linestyle=":", linewidth=0.8)
            ax.annotate(detail.split("->")[-1], (t - t0, 1.0), xycoords=("data", "axes fraction"),
                        fontsize=6, rotation=90, va="top", color="0.4")  # fmt: skip


def _confident_spans(ax, t, confident) -> None:
    on = np.nan_to_num(confident) > 0.5
    if not on.any():
        return
    edges = np.flatnonzero(np.diff(np.concatenate(([0], on.astype(int), [0]))))
    for start, stop in zip(edges[0::2], edges[1::2], strict=True):
        ax.axvspan(t[start], t[stop - 1], color="g", alpha=0.12, linewidth=0)


def plot_flight_log(
    flight: FlightLog, out_dir: Path, truth: TruthLines | None = None
) -> list[Path]:
    """Write tracking.png, estimation.png (with ``truth`` beside the estimate, if given) and
    arm.png to ``out_dir``; returns the paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def save(fig, name: str) -> Path:
        fig.tight_layout()
        path = out_dir / name
        fig.savefig(path, dpi=110)
        plt.close(fig)
        return path

    c = flight.columns
    times = c["t_vehicle_s"][np.isfinite(c["t_vehicle_s"])]
    t0 = float(times[0]) if len(times) else 0.0
    t = c["t_vehicle_s"] - t0
    title = flight.path.name

    fig, axes = plt.subplots(3, 2, figsize=(10, 8))
    panels = (
        ("q_x_m", "qd_x_m", "x [m] (east)"),
        ("q_y_m", "qd_y_m", "y [m] (north)"),
        ("q_z_m", "qd_z_m", "z [m] (up)"),
        ("q_phi_rad", "sp_roll_rad", "roll phi [rad]"),
        ("q_theta_rad", "sp_pitch_rad", "pitch theta [rad]"),
    )
    for ax, (actual, desired, label) in zip(axes.flat, panels, strict=False):
        ax.plot(t, c[desired], "r--", label="desired / setpoint")
        ax.plot(t, c[actual], "b-", label="actual")
        ax.set_xlabel("t [s]")
        ax.set_ylabel(label)
        _mode_lines(ax, flight, t0)
    axes.flat[0].legend(fontsize=7)
    ax = axes.flat[5]
    ax.plot(c["qd_x_m"], c["qd_y_m"], "r--", label="desired")
    ax.plot(c["q_x_m"], c["q_y_m"], "b-", label="actual")
    ax.set_xlabel("x [m] (east)")
    ax.set_ylabel("y [m] (north)")
    ax.set_aspect("equal", adjustable="datalim")
    fig.suptitle(f"Tracking ({title})")
    paths = [save(fig, "tracking.png")]

    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    true_values = (None, None) if truth is None else (truth.m2_kg, truth.lc_m)
    for ax, (name, label), true in zip(
        axes.flat[:2],
        (("theta_hat_m2_kg", "m2 [kg]"), ("theta_hat_lc_m", "lc [m]")),
        true_values,
        strict=True,
    ):
        _confident_spans(ax, t, c["theta_confident"])
        ax.plot(t, c[name], "b-", label="estimate (shaded: confident)")
        if truth is not None and true is not None:
            span = (truth.t_s >= t0) & (truth.t_s <= t0 + np.nanmax(t))
            ax.plot(truth.t_s[span] - t0, true[span], "k--", linewidth=1.0, label="truth")
        ax.set_xlabel("t [s]")
        ax.set_ylabel(label)
    axes.flat[0].legend(fontsize=7)
    for ax, (name, label) in zip(
        axes.flat[2:], (("theta_excitation", "excitation [-]"), ("theta_spread", "spread [-]")),
        strict=True,
    ):  # fmt: skip
        values = c[name]
        ax.plot(t, values, "k-")
        if np.any(np.isfinite(values) & (values > 0)):
            ax.set_yscale("log")
        ax.set_xlabel("t [s]")
        ax.set_ylabel(label)
    fig.suptitle(f"Payload estimation ({title})")
    paths.append(save(fig, "estimation.png"))

    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    for col, joint in enumerate(("eta1", "eta2")):
        ax = axes[0, col]
        ax.plot(t, c[f"qd_{joint}_rad"], "r--", label="desired")
        ax.plot(t, c[f"q_{joint}_rad"], "b-", label="filtered")
        ax.plot(t, c[f"servo_pos_{joint}_rad"], "g:", label="servo")
        ax.set_ylabel(f"{joint} [rad]")
        ax = axes[1, col]
        ax.plot(t, c[f"servo_tau_cmd_{joint}_n_m"], "r-", label="commanded")
        ax.plot(t, c[f"servo_tau_meas_{joint}_n_m"], "b-", label="measured")
        ax.set_ylabel(f"{joint} torque [N m]")
        for ax in axes[:, col]:
            ax.set_xlabel("t [s]")
    axes[0, 0].legend(fontsize=7)
    axes[1, 0].legend(fontsize=7)
    fig.suptitle(f"Arm ({title})")
    paths.append(save(fig, "arm.png"))
    return paths


def plot(
    log: Annotated[Path, typer.Argument(help="Flight log CSV (its .events.csv is read too).")],
    out: Annotated[
        Path,
        typer.Option(
            "--out",
            help="Output directory (created if missing); if it already holds figures, they "
            "go to OUT-2, OUT-3, ... (never overwritten).",
            show_default=False,
        ),
    ],
) -> None:
    """Draw tracking, estimation and arm figures (PNG) from a flight log."""
    if not figures_available():
        fail("companion plot needs matplotlib, which the flight install leaves out: "
             "pip install '.[plot]'")  # fmt: skip
    try:
        flight = read_flight_log(log)
    except FlightLogError as exc:
        fail(str(exc))
    for warning in flight.warnings:
        typer.echo(f"warning: {warning}", err=True)
    if len(flight) == 0:
        fail(f"{log}: the flight log has no rows")
    flight, notes = finite_only(flight)
    if not np.isfinite(flight["t_vehicle_s"]).any():
        fail(f"{log}: t_vehicle_s holds no number: nothing can be drawn against time")
    if not any(np.isfinite(flight[name]).any() for name in DRAWN_COLUMNS):
        fail(f"{log}: no column the figures draw holds a number (all empty, NaN or infinite)")
    for note in notes:
        typer.echo(f"warning: {log}: {note}", err=True)
    out = output_dir_or_exit(out, FIGURES)
    paths = plot_flight_log(flight, out)
    typer.echo(f"{log}: {len(flight)} rows; wrote {', '.join(str(p) for p in paths)}")

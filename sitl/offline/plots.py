"""Figures of simulation runs, like the paper's (section IV): tracking, q vs qhat, theta.

Uses matplotlib's non-interactive Agg backend: files only, no window.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from sitl.offline.simulation import SimResult

__all__ = ["plot_comparison", "plot_run"]

_Q = ("x", "y", "z", "phi", "theta", "psi", "eta1", "eta2")
_Q_UNITS = ("m", "m", "m", "rad", "rad", "rad", "rad", "rad")
_THETA = (("m2", "kg"), ("m3", "kg m"), ("m4", "kg m^2"), ("lc", "m"))


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_run(result: SimResult, out_dir: Path) -> list[Path]:
    """tracking.png, estimation.png and parameters.png of one run in ``out_dir``."""
    c = result.column
    t = c("t_s")
    label = f"{result.options.controller} / {result.summary.get('estimator', '')}"
    paths = []

    fig, axes = plt.subplots(3, 2, figsize=(10, 8))
    for ax, name, unit in zip(
        axes.flat[:5], ("x", "y", "z", "eta1", "eta2"), ("m", "m", "m", "rad", "rad"), strict=True
    ):
        ax.plot(t, c(f"qd_{name}"), "r--", label="desired")
        ax.plot(t, c(f"q_{name}"), "b-", label="actual")
        ax.set_xlabel("t [s]")
        ax.set_ylabel(f"{name} [{unit}]")
    axes.flat[0].legend()
    ax = axes.flat[5]
    ax.plot(c("qd_x"), c("qd_y"), "r--", label="desired")
    ax.plot(c("q_x"), c("q_y"), "b-", label="actual")
    ax.set_xlabel("x [m] (east)")
    ax.set_ylabel("y [m] (north)")
    ax.set_aspect("equal", adjustable="datalim")
    fig.suptitle(f"Trajectory tracking ({label})")
    paths.append(_save(fig, out_dir / "tracking.png"))

    fig, axes = plt.subplots(2, 4, figsize=(14, 6))
    has_qhat = not np.all(np.isnan(c("qhat_x")) & np.isnan(c("qhat_eta1")))
    for ax, name, unit in zip(axes.flat, _Q, _Q_UNITS, strict=True):
        ax.plot(t, c(f"q_{name}"), "b-", label="q (truth)")
        estimate = c(f"qhat_{name}") if has_qhat else c(f"qfilt_{name}")
        ax.plot(t, estimate, "r--", label="qhat" if has_qhat else "filtered q")
        ax.set_xlabel("t [s]")
        ax.set_ylabel(f"{name} [{unit}]")
    axes.flat[0].legend()
    kind = "estimator state qhat" if has_qhat else "filtered state"
    fig.suptitle(f"State estimation: q vs {kind} ({label})")
    paths.append(_save(fig, out_dir / "estimation.png"))

    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    for ax, (name, unit) in zip(axes.flat, _THETA, strict=True):
        ax.plot(t, c(f"{name}_true"), "k--", label="truth")
        ax.plot(t, c(f"{name}_hat"), "b-", label="estimate")
        ax.set_xlabel("t [s]")
        ax.set_ylabel(f"{name} [{unit}]")
    axes.flat[0].legend()
    fig.suptitle(f"Parameter estimates ({label})")
    paths.append(_save(fig, out_dir / "parameters.png"))
    return paths


def plot_comparison(results: Sequence[tuple[str, SimResult]], out_dir: Path) -> list[Path]:
    """Overlays of several runs: position error and the m2, lc estimates."""
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    for name, result in results:
        c = result.column
        t = c("t_s")
        err = np.linalg.norm(np.column_stack([c(f"q_{a}") - c(f"qd_{a}") for a in "xyz"]), axis=1)
        axes[0].plot(t, err, label=name)
        axes[1].plot(t, c("m2_hat"), label=name)
        axes[2].plot(t, c("lc_hat"), label=name)
    truth = results[0][1].column
    axes[1].plot(truth("t_s"), truth("m2_true"), "k--", label="truth")
    axes[2].plot(truth("t_s"), truth("lc_true"), "k--", label="truth")
    axes[0].set_ylabel("|p - p_d| [m]")
    axes[0].set_yscale("symlog", linthresh=0.01)  # a diverging run must not flatten the rest
    axes[1].set_ylabel("m2 estimate [kg]")
    axes[2].set_ylabel("lc estimate [m]")
    axes[2].set_xlabel("t [s]")
    for ax in axes:
        ax.legend(fontsize="small")
    fig.suptitle("Controllers and estimators compared")
    return [_save(fig, out_dir / "compare.png")]

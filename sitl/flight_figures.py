"""A simulated flight's figures with the truth beside the estimate: ``companion plot``'s
figures (:func:`companion.cli.mission.draw_figures`) drawn once the flight is over, with
link 2's true m2 and lc from the truth log the companion never saw."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from companion.cli.mission import draw_figures
from companion.cli.plot import TruthLines

__all__ = ["draw_with_truth", "truth_lines"]


def truth_lines(truth_log: Path) -> TruthLines:
    """Link 2's true m2 [kg] and lc = m3 / m2 [m] over simulation time from a truth log
    (``truth.jsonl``: one JSON object per line, ``t_s`` and ``true_theta``)."""
    t, m2, m3 = [], [], []
    for line in truth_log.read_text().splitlines():
        record = json.loads(line)
        t.append(record["t_s"])
        m2.append(record["true_theta"][0])
        m3.append(record["true_theta"][1])
    m2_kg = np.array(m2, dtype=float)
    return TruthLines(np.array(t, dtype=float), m2_kg, np.array(m3, dtype=float) / m2_kg)


def draw_with_truth(out_dir: Path) -> list[Path]:
    """Draw ``out_dir``'s flight figures with the truth beside the estimate (without it
    when there is no truth log); the paths drawn, none without a flight log or matplotlib
    (:func:`~companion.cli.mission.draw_figures`'s notes)."""
    truth_log = out_dir / "truth.jsonl"
    truth = truth_lines(truth_log) if truth_log.exists() else None
    return draw_figures(out_dir / "flight.csv", out_dir, truth)

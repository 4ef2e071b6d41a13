"""A simulated flight's figures with the truth beside the estimate: ``companion plot``'s
figures (:func:`companion.cli.plot.plot_flight_log`) drawn again once the flight is over,
with link 2's true m2 and lc from the truth log the companion never saw."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from companion.cli.plot import TruthLines, figures_available, plot_flight_log
from companion.logs.flightlog import FlightLogError, read_flight_log

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
    """Draw ``out_dir``'s flight figures again with the truth beside the estimate; none
    (an empty list) without matplotlib, a flight log or a truth log."""
    flight_csv, truth_log = out_dir / "flight.csv", out_dir / "truth.jsonl"
    if not (figures_available() and flight_csv.exists() and truth_log.exists()):
        return []
    try:
        flight = read_flight_log(flight_csv)
    except FlightLogError:
        return []
    return plot_flight_log(flight, out_dir, truth_lines(truth_log))

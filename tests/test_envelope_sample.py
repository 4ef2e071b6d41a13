"""The envelope as a guard on every change: ``configs/campaigns/envelope_sample.toml`` (32
draws over every axis of the shipped envelope, a fixed seed, the adaptive controller) flown
whole on simulated time, and the envelope's bounds asserted over its completed flights, as
absolute numbers: p95 |mass error| <= 3 %, p95 |CoM error| <= max(5 %, 3 mm), p95
placement <= 5 cm (numpy's default percentile); every flight completed or was refused as
beyond the vehicle's authority; and the payload's reported standard deviation, the thrust
scale's uncertainty in it, holds the true mass within two of them in >= 90 % of the flights.
A change to the estimator, controller, mission or simulator that breaks the envelope fails
here."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest

from sitl.campaign.store import refused

pytestmark = pytest.mark.slow

SPEC = Path(__file__).resolve().parents[1] / "configs" / "campaigns" / "envelope_sample.toml"


def _rows(out: Path) -> list[dict]:
    with sqlite3.connect(out / "results.sqlite") as db:
        cursor = db.execute("SELECT * FROM flights")
        names = [d[0] for d in cursor.description]
        return [dict(zip(names, r, strict=True)) for r in cursor]


def test_the_envelope_sample_holds_the_envelopes_bounds(run_sitl, tmp_path):
    out = tmp_path / "sample"
    done = run_sitl("campaign", str(SPEC), "--out", str(out), "--workers", "2", timeout=2400)
    assert done.returncode == 0, done.stdout + done.stderr
    rows = _rows(out)
    assert len(rows) == 32
    for r in rows:
        assert r["status"] == "ok" and (r["completed"] or refused(r)), (
            f"{r['flight_id']}: {r['outcome']} ({r['failure']}); replay: {r['replay']}"
        )
    flown = [r for r in rows if r["completed"]]
    assert len(flown) >= 28, f"only {len(flown)} of 32 completed"
    mass = np.abs([r["mass_error_pct"] for r in flown])
    com_over_bound = [
        abs(r["com_m"] - r["true_com_m"]) / max(0.05 * r["true_com_m"], 0.003) for r in flown
    ]
    placement = [r["placement_error_m"] for r in flown]
    figures = {
        "p95 |mass error| [%]": (float(np.percentile(mass, 95)), 3.0),
        "p95 |CoM error| / max(5 %, 3 mm)": (float(np.percentile(com_over_bound, 95)), 1.0),
        "p95 placement [m]": (float(np.percentile(placement, 95)), 0.05),
    }
    beyond = {name: value for name, (value, bound) in figures.items() if value > bound}
    assert not beyond, f"{beyond} (all: {figures})"
    within_two_std = [
        abs(r["mass_kg"] - r["true_mass_kg"]) <= 2.0 * r["mass_std_kg"] for r in flown
    ]
    assert np.mean(within_two_std) >= 0.9, within_two_std

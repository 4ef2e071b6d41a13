"""The results of a campaign: one SQLite table, ``flights``, one row per finished flight.

Why SQLite: it is in Python's standard library (nothing to install on any machine that
runs a campaign), pandas (``pd.read_sql("select * from flights", sqlite3.connect(...))``),
polars and DuckDB open it directly, and every row is its own transaction. A row is
committed the moment its flight finishes, by the one process that writes (the campaign's),
so a worker killed with ``kill -9`` or the campaign stopped with Ctrl-C loses only the
flights that had not finished; the flight's id is the table's primary key and a row is
inserted only if its id is not there yet, so nothing is ever written twice, and a rerun
flies exactly the flights whose ids are missing.

Columns: the flight's identity (id, pair id, campaign, draw, repetition, seed, controller,
autopilot, fault, place point, every key set as JSON in ``settings``), one column per axis
of the spec named by its dotted key (``"payload.mass_kg"``), the figures of
:func:`sitl.campaign.fly.flight_row`, ``status`` (``ok`` or ``error``), ``error`` (the
traceback), ``replay`` (the command that flies it alone), and the measurements of the
machine: ``wall_s``, ``cpu_s``, ``finished_unix_s``, ``worker``, ``version``.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from companion.mission.pickup import Outcome
from sitl.campaign.flights import Flight

__all__ = [
    "COLUMNS",
    "TABLE",
    "TIMING_COLUMNS",
    "CampaignMismatchError",
    "ResultsStore",
    "failed",
    "refused",
]

TABLE = "flights"
COLUMNS: tuple[tuple[str, str], ...] = (
    ("flight_id", "TEXT PRIMARY KEY"),
    ("pair_id", "TEXT NOT NULL"),
    ("campaign", "TEXT NOT NULL"),
    ("draw", "INTEGER NOT NULL"),
    ("repetition", "INTEGER NOT NULL"),
    ("seed", "INTEGER NOT NULL"),
    ("controller", "TEXT NOT NULL"),
    ("autopilot", "TEXT NOT NULL DEFAULT 'imitation'"),
    ("fault", "TEXT NOT NULL"),
    ("fault_kind", "TEXT"),
    ("fault_phase", "TEXT"),
    ("place_at_x_m", "REAL"),
    ("place_at_y_m", "REAL"),
    ("place_at_z_m", "REAL"),
    ("settings", "TEXT NOT NULL"),
    ("status", "TEXT NOT NULL"),
    ("outcome", "TEXT"),
    ("completed", "INTEGER"),
    ("faults", "TEXT"),
    ("failure", "TEXT"),
    ("true_mass_kg", "REAL"),
    ("mass_kg", "REAL"),
    ("mass_std_kg", "REAL"),
    ("mass_error_pct", "REAL"),
    ("true_com_m", "REAL"),
    ("com_m", "REAL"),
    ("com_error_pct", "REAL"),
    ("estimate_confident", "INTEGER"),
    ("placement_error_m", "REAL"),
    ("carry_rms_m", "REAL"),
    ("carry_max_error_m", "REAL"),
    ("position_rms_m", "REAL"),
    ("max_tilt_deg", "REAL"),
    ("handover_tilt_deg", "REAL"),
    ("landed", "INTEGER"),
    ("sim_s", "REAL"),
    ("control_cycles", "INTEGER"),
    ("late_cycles", "INTEGER"),
    ("poses_dropped", "INTEGER"),
    ("servo_retries", "INTEGER"),
    ("servo_failures", "INTEGER"),
    ("longest_period_ms", "REAL"),
    ("estimator_skipped_steps", "INTEGER"),
    ("cycle_latency_median_us", "REAL"),
    ("cycle_latency_p99_us", "REAL"),
    ("safe", "INTEGER"),
    ("unsafe", "TEXT"),
    ("end_state", "TEXT"),
    ("touchdown_m_s", "REAL"),
    ("payload_end", "TEXT"),
    ("error", "TEXT"),
    ("replay", "TEXT"),
    ("wall_s", "REAL"),
    ("cpu_s", "REAL"),
    ("finished_unix_s", "REAL"),
    ("worker", "INTEGER"),
    ("version", "TEXT"),
)
"""The fixed columns and their SQLite types (the axis columns come after them)."""
TIMING_COLUMNS = (
    "wall_s",
    "cpu_s",
    "finished_unix_s",
    "worker",
    "cycle_latency_median_us",
    "cycle_latency_p99_us",
)
"""Columns the machine measured: two flights of the same id differ only in these."""
_NAMES = {name for name, _ in COLUMNS}


class CampaignMismatchError(ValueError):
    """The results file holds another campaign's flights."""


def _quote(name: str) -> str:
    return '"' + name.replace('"', '""') + '"'


def identity_columns(flight: Flight) -> dict[str, Any]:
    """The columns that say which flight a row is."""
    return {
        "flight_id": flight.flight_id,
        "pair_id": flight.pair_id,
        "campaign": flight.campaign,
        "draw": flight.draw,
        "repetition": flight.repetition,
        "seed": flight.seed,
        "controller": flight.controller,
        "autopilot": flight.autopilot,
        "fault": flight.fault.label(),
        "fault_kind": flight.fault.kind,
        "fault_phase": flight.fault.at_phase,
        "place_at_x_m": flight.place_at_m[0],
        "place_at_y_m": flight.place_at_m[1],
        "place_at_z_m": flight.place_at_m[2],
        "settings": json.dumps(dict(flight.settings), sort_keys=True),
        **flight.axis_values(),
    }


class ResultsStore:
    """The ``flights`` table of a results file; :meth:`open` connects (and creates it)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._db: sqlite3.Connection | None = None

    def open(self, campaign: str, axes: Iterable[str]) -> ResultsStore:
        """Connect, create the table if new and add a column for each new axis (and each
        fixed column a table written by an earlier version lacks).

        Raises :class:`CampaignMismatchError` if the table holds another campaign's
        flights.
        """
        db = sqlite3.connect(self.path, isolation_level=None)
        self._db = db
        cols = ", ".join(f"{_quote(n)} {t}" for n, t in COLUMNS)
        db.execute(f"CREATE TABLE IF NOT EXISTS {TABLE} ({cols})")
        others = [
            r[0]
            for r in db.execute(
                f"SELECT DISTINCT campaign FROM {TABLE} WHERE campaign != ?", (campaign,)
            )
        ]
        if others:
            self.close()
            raise CampaignMismatchError(
                f"{self.path} holds the flights of the campaign {others[0]!r}, not "
                f"{campaign!r}: name another --out"
            )
        have = {r[1] for r in db.execute(f"PRAGMA table_info({TABLE})")}
        for name, kind in COLUMNS:
            if name not in have:
                db.execute(f"ALTER TABLE {TABLE} ADD COLUMN {_quote(name)} {kind}")
        for axis in axes:
            if axis in _NAMES:
                raise ValueError(f"an axis may not be named as a column: {axis!r}")
            if axis not in have:
                db.execute(f"ALTER TABLE {TABLE} ADD COLUMN {_quote(axis)}")
        return self

    @property
    def db(self) -> sqlite3.Connection:
        if self._db is None:
            raise RuntimeError("the results store is not open")
        return self._db

    def done(self) -> set[str]:
        """The ids of the flights in the table."""
        return {r[0] for r in self.db.execute(f"SELECT flight_id FROM {TABLE}")}

    def add(self, row: dict[str, Any]) -> bool:
        """Insert and commit one flight's row (its own transaction); False (nothing
        written) if its id is in the table already."""
        names = list(row)
        sql = (
            f"INSERT OR IGNORE INTO {TABLE} ({', '.join(_quote(n) for n in names)}) "
            f"VALUES ({', '.join('?' for _ in names)})"
        )
        return self.db.execute(sql, [row[n] for n in names]).rowcount == 1

    def rows(self) -> list[dict[str, Any]]:
        """Every row, as dicts, in the table's order."""
        cursor = self.db.execute(f"SELECT * FROM {TABLE} ORDER BY rowid")
        names = [d[0] for d in cursor.description]
        return [dict(zip(names, r, strict=True)) for r in cursor]

    def close(self) -> None:
        """Disconnect (idempotent)."""
        if self._db is not None:
            self._db.close()
            self._db = None

    def __enter__(self) -> ResultsStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def refused(row: dict[str, Any]) -> bool:
    """A flight whose payload the companion refused (in the grasp or the lift's first
    centimetres) as beyond the vehicle's or the servos' authority (``beyond_authority``):
    a safe refusal, not a failure."""
    return row.get("status") == "ok" and row.get("outcome") == Outcome.BEYOND_AUTHORITY.value


def failed(row: dict[str, Any]) -> bool:
    """A flight that crashed (``error``) or did not complete, refusals left out."""
    return row.get("status") == "error" or not (row.get("completed") or refused(row))

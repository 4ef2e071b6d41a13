"""The flight log's columns: one float64 row per control cycle, preallocated in blocks,
and the binary file they are written to in flight.

A cycle writes its numbers into the next row of a block (:class:`LogColumns`): the
columns of ``LOG.csv`` (:data:`COLUMNS`) in file order, then the wall-clock columns of
``LOG.timing.csv``. Flags are 0 / 1; text (PX4's mode, the mission phase, the faults) is a
code into :attr:`LogColumns.texts`; NaN is a value that was not available. The writers
(:class:`~companion.logs.flightlog.FlightLogWriter`, the MCAP of
:mod:`companion.logs.mcap_log`) write a full block in one go, between cycles: the cycle
itself formats nothing.

``LOG.columns`` (:class:`ColumnsFile`), the rows as the flight goes, in the way of PX4's
ULog: the line :data:`MAGIC`, a JSON line naming the columns (:data:`ROW`), then records,
each a kind byte, its payload's length (uint32, little-endian) and the payload: ``T`` a new
text (UTF-8; the n-th text is code n, code 0 the empty text), ``R`` rows (float64,
little-endian, :data:`WIDTH` per row). :func:`read_columns` reads it up to where a crash cut
it.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import struct
from pathlib import Path
from typing import IO

import numpy as np
from numpy.typing import NDArray

from companion.user_files import UserFileError, open_regular_file

__all__ = [
    "COLUMNS",
    "FLAG_COLUMNS",
    "MAGIC",
    "ROW",
    "TEXT_COLUMNS",
    "TIMING_COLUMNS",
    "WIDTH",
    "ColumnsError",
    "ColumnsFile",
    "LogColumns",
    "csv_lines",
    "fsync",
    "read_columns",
    "write_csv",
]

Q_NAMES = ("x", "y", "z", "phi", "theta", "psi", "eta1", "eta2")
_Q_UNITS = ("m", "m", "m", "rad", "rad", "rad", "rad", "rad")
_TAU_UNITS = ("n", "n", "n", "n_m", "n_m", "n_m", "n_m", "n_m")
_JOINTS = ("eta1", "eta2")

_THETA = ("theta_hat_m2_kg", "theta_hat_m3_kg_m", "theta_hat_m4_kg_m2", "theta_hat_lc_m")
_SETPOINT = (
    "sp_roll_rad",
    "sp_pitch_rad",
    "sp_yaw_rad",
    "sp_thrust_n",
    "thrust_rel",
    "sp_tilt_saturated",
    "sp_thrust_saturated",
)
TEXT_COLUMNS = ("px4_mode", "phase", "faults")
"""Columns holding text (a code in the row); every other column is numeric."""
FLAG_COLUMNS = (
    "theta_confident",
    "theta_frozen",
    "sp_tilt_saturated",
    "sp_thrust_saturated",
    "armed",
)
"""Columns holding a flag (0 / 1; NaN: not known)."""

COLUMNS: tuple[str, ...] = (
    "t_vehicle_s",
    *(f"q_{n}_{u}" for n, u in zip(Q_NAMES, _Q_UNITS, strict=True)),
    *(f"qdot_{n}_{u}_s" for n, u in zip(Q_NAMES, _Q_UNITS, strict=True)),
    *(f"qddot_{n}_{u}_s2" for n, u in zip(Q_NAMES, _Q_UNITS, strict=True)),
    *(f"qd_{n}_{u}" for n, u in zip(Q_NAMES, _Q_UNITS, strict=True)),
    *_THETA,
    "theta_excitation",
    "theta_spread",
    "theta_confident",
    "theta_frozen",
    "thrust_scale_hat",
    *(f"tau_{n}_{u}" for n, u in zip(Q_NAMES, _TAU_UNITS, strict=True)),
    *_SETPOINT,
    *(f"servo_tau_cmd_{j}_n_m" for j in _JOINTS),
    *(f"servo_tau_meas_{j}_n_m" for j in _JOINTS),
    *(f"servo_pos_{j}_rad" for j in _JOINTS),
    "loop_period_ms",
    "px4_mode",
    "armed",
    "phase",
    "faults",
)
"""Every column of ``LOG.csv``, in file order."""

TIMING_COLUMNS: tuple[str, ...] = (
    "t_vehicle_s",
    "t_wall_s",
    "setpoint_latency_us",
    "cycle_latency_us",
    "setpoint_cpu_us",
)
"""Every column of ``LOG.timing.csv``, in file order."""

ROW: tuple[str, ...] = (*COLUMNS, *TIMING_COLUMNS[1:])
"""A row of the columns: :data:`COLUMNS`, then the timing file's wall-clock columns."""
WIDTH = len(ROW)
INDEX = {name: i for i, name in enumerate(ROW)}
"""Column name -> its index in a row."""


def _span(first: str, n: int) -> slice:
    start = INDEX[first]
    return slice(start, start + n)


T = INDEX["t_vehicle_s"]
Q = _span("q_x_m", 8)
Q_DOT = _span("qdot_x_m_s", 8)
Q_DDOT = _span("qddot_x_m_s2", 8)
Q_D = _span("qd_x_m", 8)
THETA = _span("theta_hat_m2_kg", 3)
LC = INDEX["theta_hat_lc_m"]
EXCITATION = INDEX["theta_excitation"]
SPREAD = INDEX["theta_spread"]
CONFIDENT = INDEX["theta_confident"]
FROZEN = INDEX["theta_frozen"]
THRUST_SCALE = INDEX["thrust_scale_hat"]
TAU = _span("tau_x_n", 8)
SETPOINT = _span("sp_roll_rad", 7)
SERVO_CMD = _span("servo_tau_cmd_eta1_n_m", 2)
SERVO_MEAS = _span("servo_tau_meas_eta1_n_m", 2)
SERVO_POS = _span("servo_pos_eta1_rad", 2)
PERIOD = INDEX["loop_period_ms"]
MODE = INDEX["px4_mode"]
ARMED = INDEX["armed"]
PHASE = INDEX["phase"]
FAULTS = INDEX["faults"]
T_WALL = INDEX["t_wall_s"]
SETPOINT_LATENCY = INDEX["setpoint_latency_us"]
CYCLE_LATENCY = INDEX["cycle_latency_us"]
SETPOINT_CPU = INDEX["setpoint_cpu_us"]

_CSV_WIDTH = len(COLUMNS)
_FLAGS = tuple(INDEX[name] for name in FLAG_COLUMNS)
_TEXTS = tuple(INDEX[name] for name in TEXT_COLUMNS)
_FLAG_CELLS = {0.0: "0", 1.0: "1"}


def _csv_cell(text: str) -> str:
    """``text`` as one CSV cell (quoted where the csv module quotes it in a row)."""
    if not text:
        return ""  # the csv module quotes an empty cell only when it is a row's one cell
    out = io.StringIO()
    csv.writer(out, lineterminator="").writerow((text,))
    return out.getvalue()


class LogColumns:
    """A preallocated block of rows (:data:`ROW`) and the text codes of the flight.

    :meth:`next_row` gives the row a cycle fills (all NaN), :meth:`take` the rows filled
    since the last take. Text is stored as :meth:`code`: the index of the text in
    :attr:`texts`, which grows as new texts appear (code 0 is the empty text).
    """

    def __init__(self, rows: int) -> None:
        if rows < 1:
            raise ValueError("a block holds at least one row")
        self.block = np.full((rows, WIDTH), math.nan)
        self.n = 0
        """Rows filled in the block."""
        self.texts: list[str] = [""]
        """Code -> text."""
        self._codes: dict[str, float] = {"": 0.0}

    @property
    def full(self) -> bool:
        return self.n == len(self.block)

    def code(self, text: str) -> float:
        """The code of ``text`` (a new one for a text not seen before)."""
        code = self._codes.get(text)
        if code is None:
            code = self._codes[text] = float(len(self.texts))
            self.texts.append(text)
        return code

    def next_row(self) -> NDArray[np.float64]:
        """The next row of the block (a view, all NaN); the block must not be full."""
        row = self.block[self.n]
        self.n += 1
        return row

    def take(self) -> NDArray[np.float64]:
        """A copy of the rows filled since the last take; the block is empty (NaN) again."""
        rows = self.block[: self.n].copy()
        self.block[: self.n] = math.nan
        self.n = 0
        return rows


def csv_lines(rows: NDArray[np.float64], cells: list[str]) -> tuple[str, str]:
    """The lines of ``LOG.csv`` and of ``LOG.timing.csv`` of ``rows`` (pure): numbers as
    Python's shortest round-trip repr, NaN as an empty cell, flags as 0 / 1, text codes
    as their CSV ``cells``; each line ends with CR LF (the csv module's)."""
    main: list[str] = []
    timing: list[str] = []
    for row in rows.tolist():
        line = repr(row)[1:-1].replace("nan", "").split(", ")
        for i in _FLAGS:
            line[i] = _FLAG_CELLS.get(row[i], "")
        for i in _TEXTS:
            code = row[i]
            line[i] = cells[int(code)] if code == code else ""
        main.append(",".join(line[:_CSV_WIDTH]))
        timing.append(",".join((line[0], *line[_CSV_WIDTH:])))
    if not main:
        return "", ""
    return "\r\n".join(main) + "\r\n", "\r\n".join(timing) + "\r\n"


MAGIC = b"companion flight columns 1\n"
_RECORD = struct.Struct("<cI")
_ROWS, _TEXT = b"R", b"T"


class ColumnsError(Exception):
    """A columns file that cannot be written or read; the message names the file."""


class ColumnsFile:
    """``LOG.columns`` written as the flight goes (module docstring): :meth:`write` a block
    of rows with the texts that appeared since the last, handed to the operating system at
    once (no fsync). Opened exclusively (never overwritten) by :meth:`open`."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._file: IO[bytes] | None = None
        self._texts = 1
        """Texts written so far (code 0, the empty text, is not written)."""

    def open(self) -> None:
        self._file = open(self.path, "xb")
        header = json.dumps({"columns": ROW, "dtype": "<f8"}).encode() + b"\n"
        self._file.write(MAGIC + header)
        self._file.flush()

    def write(self, rows: NDArray[np.float64], texts: list[str]) -> None:
        """Append the new ``texts`` (code order) and ``rows``, then hand them to the OS."""
        f = self._file
        if f is None:
            raise ColumnsError(f"{self.path}: not open")
        for text in texts[self._texts :]:
            data = text.encode("utf-8")
            f.write(_RECORD.pack(_TEXT, len(data)) + data)
        self._texts = len(texts)
        if len(rows):
            data = np.ascontiguousarray(rows, dtype="<f8").tobytes()
            f.write(_RECORD.pack(_ROWS, len(data)) + data)
        f.flush()

    def close(self) -> None:
        """Close (idempotent; no fsync: the CSV written from it is what is kept)."""
        f, self._file = self._file, None
        if f is not None:
            f.close()


def read_columns(path: Path) -> tuple[NDArray[np.float64], list[str], list[str]]:
    """The rows [n, :data:`WIDTH`], the texts (by code) and the warnings (a record cut by
    a crash: the rows before it are read) of ``LOG.columns`` (a regular file only:
    :func:`companion.user_files.open_regular_file`)."""
    try:
        with open_regular_file(path) as f:
            data = f.read()
    except UserFileError as exc:
        raise ColumnsError(str(exc)) from None
    except OSError as exc:
        raise ColumnsError(f"{path}: cannot read: {exc.strerror}") from None
    if not data.startswith(MAGIC):
        raise ColumnsError(f"{path}: not a flight columns file")
    end = data.find(b"\n", len(MAGIC))
    try:
        header = json.loads(data[len(MAGIC) : end])
    except ValueError:
        header = None
    if end < 0 or not isinstance(header, dict) or tuple(header.get("columns", ())) != ROW:
        raise ColumnsError(f"{path}: its columns are not this version's")
    texts, blocks, warnings = [""], [], []
    pos = end + 1
    while pos < len(data):
        if pos + _RECORD.size > len(data):
            warnings.append(f"{path}: cut short (a crash?): read the records before the cut")
            break
        kind, size = _RECORD.unpack_from(data, pos)
        payload = data[pos + _RECORD.size : pos + _RECORD.size + size]
        if (
            len(payload) < size
            or kind not in (_ROWS, _TEXT)
            or (kind == _ROWS and size % (8 * WIDTH))
        ):
            warnings.append(f"{path}: cut short (a crash?): read the records before the cut")
            break
        if kind == _TEXT:
            texts.append(payload.decode("utf-8", errors="replace"))
        else:
            blocks.append(np.frombuffer(payload, dtype="<f8").reshape(-1, WIDTH))
        pos += _RECORD.size + size
    rows = np.concatenate(blocks) if blocks else np.empty((0, WIDTH))
    return rows, texts, warnings


def write_csv(rows: NDArray[np.float64], texts: list[str], main: IO[str], timing: IO[str]) -> None:
    """``rows`` as the lines of ``LOG.csv`` into ``main`` and of ``LOG.timing.csv`` into
    ``timing`` (after their headers), in blocks."""
    cells = [_csv_cell(text) for text in texts]
    for start in range(0, len(rows), 1024):
        lines, timing_lines = csv_lines(rows[start : start + 1024], cells)
        main.write(lines)
        timing.write(timing_lines)


def fsync(path: Path) -> None:
    """Flush ``path``'s data to the disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)

"""Flight log: one CSV row per control cycle, a CSV of events and a CSV of timing beside it.

Format
------
``LOG.csv`` (e.g. ``flight.csv``): UTF-8 CSV, one header row, then one row per control
cycle; it opens as is in pandas (``pd.read_csv``), spreadsheets and
:func:`read_flight_log`. Column names carry their SI unit (``x_m``, ``thrust_rel``);
frames are ours (world ENU, body FLU, ZYX Euler angles, DESIGN.md section 2). Numbers are
written exactly (Python's shortest round-trip repr); an empty cell is a value that was
not available that cycle (read back as NaN); flags are 0 / 1.

=================================  =========================================================
columns                            content
=================================  =========================================================
``t_vehicle_s``                    vehicle clock (time_boot_ms / 1000) [s]
``q_<i>_<u>``                      q: x y z [m], phi theta psi eta1 eta2 [rad]
``qdot_<i>_<u>_s``                 filtered q_dot [m/s, rad/s]
``qddot_<i>_<u>_s2``               filtered q_ddot [m/s^2, rad/s^2]
``qd_<i>_<u>``                     desired q
``theta_hat_m2_kg`` ...            estimates m2 [kg], m3 [kg m], m4 [kg m^2], lc = m3/m2 [m]
``theta_excitation``, ``_spread``  the estimator's confidence inputs (dimensionless)
``theta_confident``, ``_frozen``   its flags
``thrust_scale_hat``               estimated thrust scale s (true over modelled thrust; 1
                                   when not estimated)
``tau_<i>_<u>``                    controller output tau: x y z [N], phi theta psi eta1 eta2
                                   [N m] (generalized forces, DESIGN.md section 2)
``sp_roll_rad`` ... ``thrust_rel`` attitude setpoint (ENU/FLU Euler), thrust [N], PX4
                                   relative thrust, saturation flags
``servo_tau_cmd_eta<j>_n_m``       joint torque commanded / measured (present current)
``servo_tau_meas_eta<j>_n_m``      [N m]
``servo_pos_eta<j>_rad``           joint position read from the servos [rad]
``loop_period_ms``                 vehicle time since the previous control cycle [ms]
``px4_mode``, ``armed``            PX4 mode name, armed flag
``phase``, ``faults``              mission phase; active faults, ``;``-separated
=================================  =========================================================

``LOG.timing.csv``: what the wall clock measured, one row per row of ``LOG.csv``:

=================================  =========================================================
``t_vehicle_s``, ``t_wall_s``      vehicle clock and Unix time [s]
``setpoint_latency_us``            pose taken from the link -> setpoint sent, this cycle [us]
``cycle_latency_us``               pose taken from the link -> joint torques handed to the
                                   arm task, this cycle [us] (empty: nothing was sent)
``setpoint_cpu_us``                the companion thread's CPU time over
                                   ``setpoint_latency_us`` [us]: the rest of that time it
                                   waited for a core
=================================  =========================================================

Measurements are kept apart so that ``LOG.csv`` and ``LOG.events.csv`` hold only what the
flight did, on the vehicle's clock: a flight on simulated time (:mod:`sitl.vehicle.lockstep`)
writes them byte for byte the same at any speed and load; only ``LOG.timing.csv`` differs.
:func:`read_flight_log` reads the three files into one set of columns.

``LOG.events.csv``: columns ``t_vehicle_s, kind, detail``, one row per event.
Kinds written by the writer itself: ``mode`` (PX4 mode changed; detail ``OLD->NEW``),
``phase`` (mission phase changed), ``fault`` / ``fault_cleared`` (a fault name appeared in
/ left ``faults``); the application adds its own with :meth:`FlightLogWriter.event`.

Timing
------
Writing never waits on the disk for long: a row is formatted (tens of microseconds) into
a 1 MiB user-space buffer; every ``flush_every_rows`` rows (default 250, one second at
250 Hz) and at each event the buffer is handed to the operating system (a copy into the
page cache, well under a millisecond, no fsync). :meth:`FlightLogWriter.close` flushes and
fsyncs. A crash loses at most the last ``flush_every_rows`` rows.
"""

from __future__ import annotations

import csv
import math
import os
import time
from array import array
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, BinaryIO

import numpy as np
from numpy.typing import ArrayLike, NDArray

from companion.user_files import UserFileError, open_regular_file

if TYPE_CHECKING:
    from companion.control.setpoints import AttitudeThrustSetpoint

__all__ = [
    "COLUMNS",
    "TEXT_COLUMNS",
    "TIMING_COLUMNS",
    "CycleRecord",
    "FlightLog",
    "FlightLogError",
    "FlightLogWriter",
    "events_path",
    "format_row",
    "format_timing_row",
    "read_flight_log",
    "timing_path",
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
"""Columns holding text; every other column is numeric."""

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

EVENT_COLUMNS = ("t_vehicle_s", "kind", "detail")


class FlightLogError(Exception):
    """A flight log that cannot be written or read; the message names the file."""


def events_path(log_path: str | Path) -> Path:
    """``flight.csv`` -> ``flight.events.csv``."""
    path = Path(log_path)
    return path.with_name(f"{path.stem}.events.csv")


def timing_path(log_path: str | Path) -> Path:
    """``flight.csv`` -> ``flight.timing.csv``."""
    path = Path(log_path)
    return path.with_name(f"{path.stem}.timing.csv")


@dataclass(frozen=True)
class CycleRecord:
    """What one control cycle logs. Arrays are in q order (:data:`Q_NAMES`); parts that
    are None are written as empty cells.

    Parameters
    ----------
    t_vehicle_s : float
        Vehicle time (time_boot_ms / 1000) [s].
    q, q_dot, q_ddot, q_d : array_like, shape (8,)
        Measured / filtered state and its desired value (SI, ENU/FLU, ZYX Euler).
    theta_hat : array_like, shape (3,)
        (m2 [kg], m3 [kg m], m4 [kg m^2]).
    tau : array_like, shape (8,)
        Controller output (generalized forces: N, N m).
    setpoint : AttitudeThrustSetpoint
        What was sent to PX4.
    servo_torque_cmd_n_m, servo_torque_meas_n_m, servo_position_rad : array_like, shape (2,)
        Joint torque commands, torques from present current, joint positions.
    loop_period_ms, setpoint_latency_us, cycle_latency_us, setpoint_cpu_us : float, optional
        The cycle's timing: vehicle time since the previous cycle [ms]; wall time from the
        pose taken off the link to the setpoint sent and to the joint torques handed to the
        arm task [us]; the thread's CPU time from the pose to the setpoint [us].
    faults : sequence of str
        Names of the active faults (no ``;`` in a name).
    t_wall_s : float, optional
        Unix time [s]; the writer reads the clock if None. The timing values and this go
        to ``LOG.timing.csv``.
    """

    t_vehicle_s: float
    q: ArrayLike | None = None
    q_dot: ArrayLike | None = None
    q_ddot: ArrayLike | None = None
    q_d: ArrayLike | None = None
    theta_hat: ArrayLike | None = None
    theta_excitation: float | None = None
    theta_spread: float | None = None
    theta_confident: bool | None = None
    theta_frozen: bool | None = None
    thrust_scale_hat: float | None = None
    tau: ArrayLike | None = None
    setpoint: AttitudeThrustSetpoint | None = None
    servo_torque_cmd_n_m: ArrayLike | None = None
    servo_torque_meas_n_m: ArrayLike | None = None
    servo_position_rad: ArrayLike | None = None
    loop_period_ms: float | None = None
    setpoint_latency_us: float | None = None
    cycle_latency_us: float | None = None
    setpoint_cpu_us: float | None = None
    px4_mode: str = ""
    armed: bool | None = None
    phase: str = ""
    faults: Sequence[str] = ()
    t_wall_s: float | None = None


def _num(value: float | None) -> str:
    return "" if value is None else repr(float(value))


def _flag(value: bool | None) -> str:
    return "" if value is None else ("1" if value else "0")


def _vec(name: str, values: ArrayLike | None, n: int) -> list[str]:
    if values is None:
        return [""] * n
    arr = np.asarray(values, dtype=np.float64).reshape(-1)
    if arr.size != n:
        raise FlightLogError(f"{name} must have {n} entries, got {arr.size}")
    return list(map(repr, arr.tolist()))


def format_row(record: CycleRecord) -> list[str]:
    """The cells of one row, in :data:`COLUMNS` order (pure)."""
    r = record
    if r.theta_hat is None:
        theta = [""] * 4
    else:
        theta = _vec("theta_hat", r.theta_hat, 3)
        m2, m3 = float(theta[0]), float(theta[1])
        theta.append(repr(m3 / m2) if m2 != 0.0 else "nan")
    sp = r.setpoint
    setpoint = (
        [""] * 7
        if sp is None
        else [
            *(_num(v) for v in (sp.roll_rad, sp.pitch_rad, sp.yaw_rad, sp.thrust_n)),
            _num(sp.thrust_relative),
            _flag(sp.tilt_saturated),
            _flag(sp.thrust_saturated),
        ]
    )
    return [
        _num(r.t_vehicle_s),
        *_vec("q", r.q, 8),
        *_vec("q_dot", r.q_dot, 8),
        *_vec("q_ddot", r.q_ddot, 8),
        *_vec("q_d", r.q_d, 8),
        *theta,
        _num(r.theta_excitation),
        _num(r.theta_spread),
        _flag(r.theta_confident),
        _flag(r.theta_frozen),
        _num(r.thrust_scale_hat),
        *_vec("tau", r.tau, 8),
        *setpoint,
        *_vec("servo_torque_cmd_n_m", r.servo_torque_cmd_n_m, 2),
        *_vec("servo_torque_meas_n_m", r.servo_torque_meas_n_m, 2),
        *_vec("servo_position_rad", r.servo_position_rad, 2),
        _num(r.loop_period_ms),
        r.px4_mode,
        _flag(r.armed),
        r.phase,
        ";".join(r.faults),
    ]


def format_timing_row(record: CycleRecord, t_wall_s: float) -> list[str]:
    """The cells of one timing row, in :data:`TIMING_COLUMNS` order (pure)."""
    r = record
    return [
        _num(r.t_vehicle_s),
        _num(t_wall_s),
        _num(r.setpoint_latency_us),
        _num(r.cycle_latency_us),
        _num(r.setpoint_cpu_us),
    ]


class FlightLogWriter:
    """Writes ``LOG.csv``, ``LOG.events.csv`` and ``LOG.timing.csv`` (see the module
    docstring).

    Nothing is opened in the constructor; use ``with FlightLogWriter(path) as log`` or
    :meth:`open` / :meth:`close` (idempotent). A log is never overwritten: :meth:`open`
    raises :class:`FlightLogError` if any of the files exists.

    Parameters
    ----------
    path : str or Path
        The cycle log; its directory must exist.
    flush_every_rows : int
        Hand buffered rows to the OS every this many rows.
    """

    def __init__(self, path: str | Path, flush_every_rows: int = 250) -> None:
        if flush_every_rows < 1:
            raise ValueError("flush_every_rows must be at least 1")
        self.path = Path(path)
        self.events_path = events_path(self.path)
        self.timing_path = timing_path(self.path)
        self.flush_every_rows = flush_every_rows
        self.rows = 0
        self._files: list[IO[str]] = []
        self._rows: Any = None
        self._events: Any = None
        self._timing: Any = None
        self._mode = ""
        self._phase = ""
        self._faults: frozenset[str] = frozenset()
        self._closed = False

    def __enter__(self) -> FlightLogWriter:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> None:
        if self._files or self._closed:
            raise FlightLogError(f"{self.path}: a FlightLogWriter opens once")
        try:
            for p in (self.path, self.events_path, self.timing_path):
                f = open(p, "x", newline="", encoding="utf-8", buffering=1 << 20)
                self._files.append(f)
        except FileExistsError as exc:
            self.close()
            raise FlightLogError(
                f"{exc.filename}: exists; a flight log is never overwritten"
            ) from None
        except OSError as exc:
            self.close()
            raise FlightLogError(f"{exc.filename}: cannot write: {exc.strerror}") from None
        self._rows = csv.writer(self._files[0])
        self._events = csv.writer(self._files[1])
        self._timing = csv.writer(self._files[2])
        self._rows.writerow(COLUMNS)
        self._events.writerow(EVENT_COLUMNS)
        self._timing.writerow(TIMING_COLUMNS)

    def write(self, record: CycleRecord) -> None:
        """Append one cycle; writes ``mode`` / ``phase`` / ``fault`` events on changes."""
        if self._rows is None:
            raise FlightLogError(f"{self.path}: the log is not open")
        t_wall = time.time() if record.t_wall_s is None else record.t_wall_s
        self._rows.writerow(format_row(record))
        self._timing.writerow(format_timing_row(record, t_wall))
        self.rows += 1
        t = record.t_vehicle_s
        if record.px4_mode != self._mode:
            self.event("mode", f"{self._mode}->{record.px4_mode}", t)
            self._mode = record.px4_mode
        if record.phase != self._phase:
            self.event("phase", f"{self._phase}->{record.phase}", t)
            self._phase = record.phase
        faults = frozenset(record.faults)
        if faults != self._faults:
            for name in sorted(faults - self._faults):
                self.event("fault", name, t)
            for name in sorted(self._faults - faults):
                self.event("fault_cleared", name, t)
            self._faults = faults
        if self.rows % self.flush_every_rows == 0:
            self._files[0].flush()
            self._files[2].flush()

    def event(self, kind: str, detail: str, t_vehicle_s: float) -> None:
        """Append an event (flushed at once: events are rare and matter after a crash)."""
        if self._events is None:
            raise FlightLogError(f"{self.path}: the log is not open")
        self._events.writerow((_num(t_vehicle_s), kind, detail))
        self._files[1].flush()

    def close(self) -> None:
        """Flush, fsync and close the files (idempotent)."""
        self._closed = True
        files, self._files = self._files, []
        self._rows = self._events = self._timing = None
        for f in files:
            f.flush()
            os.fsync(f.fileno())
            f.close()


@dataclass(frozen=True)
class FlightLog:
    """A flight log read back: one numpy array per column, and the events."""

    path: Path
    columns: dict[str, NDArray]
    """Numeric columns as float64 (empty cells NaN); :data:`TEXT_COLUMNS` as str arrays;
    the timing columns too (NaN without a timing file)."""
    events: dict[str, NDArray]
    """Event columns (``t_vehicle_s`` float64; ``kind``, ``detail`` str)."""
    warnings: tuple[str, ...] = ()
    """What was left out on reading: a last line cut by a crash or a power cut."""

    def __getitem__(self, name: str) -> NDArray:
        return self.columns[name]

    def __len__(self) -> int:
        return len(self.columns["t_vehicle_s"])


MAX_ROW_BYTES = 1 << 16
"""The longest line read from a flight log [bytes]: a row of :data:`COLUMNS` is under
2 KiB; a longer line is not a flight log's (and is not held in memory)."""


def _only_zeros(f: BinaryIO) -> bool:
    """Whether the rest of ``f`` is zero bytes (read in chunks, never whole)."""
    while chunk := f.read(1 << 16):
        if chunk.strip(b"\0"):
            return False
    return True


def _whole_lines(f: BinaryIO, path: Path, warnings: list[str]) -> Iterator[str]:
    """The lines of ``f`` (each with its line end), read one at a time, up to the last
    whole row: a row the writer finished ends with a newline; a crash or a power cut leaves
    the last one cut (and on some file systems zeros after it). The cut part is dropped
    and named in ``warnings``."""
    line_no = 0
    while line := f.readline(MAX_ROW_BYTES + 1):
        if not line.endswith(b"\n"):  # the file's end, or a line too long
            kept = line.rstrip(b"\0")
            if len(line) > MAX_ROW_BYTES and (len(kept) == len(line) or not _only_zeros(f)):
                raise FlightLogError(
                    f"{path}, line {line_no + 1}: longer than {MAX_ROW_BYTES} bytes: "
                    "not a CSV flight log"
                )
            if kept and not kept.endswith(b"\r"):
                if line_no == 0:
                    raise FlightLogError(
                        f"{path}: the header row is cut (the file ends after {len(kept)} bytes)"
                    )
                warnings.append(
                    f"{path}: line {line_no + 1} is cut (a crash or a power cut?): read the "
                    "whole rows before it"
                )
                return
            line = kept
        line_no += 1
        try:
            yield line.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise FlightLogError(f"{path}, line {line_no}: not a CSV flight log: {exc}") from None


_ADDED_COLUMNS = ("thrust_scale_hat",)
"""Columns added after logs were first written: such a log reads with NaN in them."""


def _read_csv(
    path: Path, expected: Sequence[str], text: Iterable[str], warnings: list[str]
) -> dict[str, NDArray]:
    """One CSV file of a flight log, streamed row by row into its columns
    (:func:`companion.user_files.open_regular_file`: a FIFO or a device is refused unread)."""
    try:
        f = open_regular_file(path)
    except UserFileError as exc:
        raise FlightLogError(str(exc)) from None
    with f:
        rows = csv.reader(_whole_lines(f, path, warnings))
        try:
            header = next(rows, None)
            if header is None:
                raise FlightLogError(f"{path}: empty file, expected a header row")
            columns = _columns(path, header, expected, set(text), rows)
        except csv.Error as exc:
            raise FlightLogError(
                f"{path}, line {rows.line_num}: not a CSV flight log: {exc}"
            ) from None
        except OSError as exc:
            raise FlightLogError(f"{path}: cannot read: {exc.strerror or exc}") from None
    return columns


def _columns(
    path: Path,
    header: list[str],
    expected: Sequence[str],
    text: set[str],
    rows: Any,
) -> dict[str, NDArray]:
    """The columns of the rows after ``header`` (numbers as float64, ``text`` as str)."""
    older = tuple(c for c in expected if c not in _ADDED_COLUMNS)
    if tuple(header) not in (tuple(expected), older):
        missing = [c for c in expected if c not in header]
        unknown = [c for c in header if c not in expected]
        raise FlightLogError(
            f"{path}: not a flight log header (missing {missing[:5]}, unknown {unknown[:5]})"
        )
    numbers: dict[str, array[float]] = {n: array("d") for n in header if n not in text}
    strings: dict[str, list[str]] = {n: [] for n in header if n in text}
    n_rows = 0
    for row in rows:
        if len(row) != len(header):
            raise FlightLogError(
                f"{path}, line {rows.line_num}: {len(row)} cells, expected {len(header)}"
            )
        for name, cell in zip(header, row, strict=True):
            if name in text:
                strings[name].append(cell)
                continue
            try:
                numbers[name].append(float(cell) if cell else math.nan)
            except ValueError:
                raise FlightLogError(
                    f"{path}, line {rows.line_num}: {name} = {cell!r} is not a number"
                ) from None
        n_rows += 1
    columns: dict[str, NDArray] = {n: np.array(v, dtype=str) for n, v in strings.items()}
    columns.update((n, np.frombuffer(v, dtype=np.float64).copy()) for n, v in numbers.items())
    missing = [name for name in expected if name not in columns]  # added columns only
    columns.update((name, np.full(n_rows, math.nan)) for name in missing)
    return {name: columns[name] for name in expected}


def read_flight_log(path: str | Path) -> FlightLog:
    """Read ``LOG.csv``, ``LOG.events.csv`` (absent: no events) and ``LOG.timing.csv``
    (absent: its columns NaN).

    A last line cut by a crash or a power cut is left out and named in
    :attr:`FlightLog.warnings`. Raises ``FlightLogError`` naming the file and line for a
    missing file, a foreign header, a ragged row or a non-numeric cell.
    """
    path = Path(path)
    warnings: list[str] = []
    columns = _read_csv(path, COLUMNS, TEXT_COLUMNS, warnings)
    n = len(columns["t_vehicle_s"])
    t_path = timing_path(path)
    timing = _read_csv(t_path, TIMING_COLUMNS, (), warnings) if t_path.exists() else {}
    for name in TIMING_COLUMNS[1:]:
        values = timing.get(name, np.full(n, math.nan))
        if len(values) != n:  # a crash cut the two files at different rows
            kept = values[:n]
            values = np.concatenate([kept, np.full(n - len(kept), math.nan)])
        columns[name] = values
    ev_path = events_path(path)
    if ev_path.exists():
        events = _read_csv(ev_path, EVENT_COLUMNS, ("kind", "detail"), warnings)
    else:
        events = {
            name: np.array([], dtype=str if name in ("kind", "detail") else np.float64)
            for name in EVENT_COLUMNS
        }
    return FlightLog(path, columns, events, tuple(warnings))

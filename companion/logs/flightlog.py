"""Flight log: one CSV row per control cycle, a CSV of events and a CSV of timing beside it,
written from binary columns (:mod:`companion.logs.columns`).

Format
------
``LOG.csv`` (e.g. ``flight.csv``): UTF-8 CSV, one header row, then one row per control
cycle; it opens as is in pandas (``pd.read_csv``), spreadsheets and
:func:`read_flight_log`. Column names carry their SI unit (``x_m``, ``thrust_rel``);
frames are ours (world ENU, body FLU, ZYX Euler angles, DESIGN.md section 2). Numbers are
written exactly (Python's shortest round-trip repr); an empty cell is a value that was
not available that cycle or not a number (NaN; read back as NaN); flags are 0 / 1.

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

Writing and crashes
-------------------
A control cycle formats nothing: it writes its numbers into the next row of a
preallocated block of columns (:mod:`companion.logs.columns`: float64, flags 0 / 1, text
as codes). Every :data:`BLOCK_ROWS` rows (80 ms at 125 Hz), in the cycle that fills the
block, and before each event, the block goes in one write to ``LOG.columns`` (binary, in
the way of PX4's ULog) and is handed to the operating system (no fsync); events go to
``LOG.events.csv`` at once. :meth:`FlightLogWriter.close` writes the last block, then the
rows of ``LOG.csv`` and ``LOG.timing.csv`` from the columns (exact decimal text is the
costly part, about 45 us a row: it is done once, after the flight), fsyncs and removes
``LOG.columns``. A crash or a ``kill -9`` loses at most the rows of the block not yet
written (:data:`BLOCK_ROWS`); what was written stays readable: ``LOG.csv`` holds its
header, ``LOG.columns`` the rows, and :func:`export_columns` (``companion log export``)
writes the CSV files from it.
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

from companion.logs import columns
from companion.logs.columns import (
    ColumnsError,
    ColumnsFile,
    LogColumns,
    fsync,
    read_columns,
    write_csv,
)
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
    "columns_path",
    "events_path",
    "export_columns",
    "fill_row",
    "read_flight_log",
    "timing_path",
]

Q_NAMES = columns.Q_NAMES
TEXT_COLUMNS = columns.TEXT_COLUMNS
COLUMNS = columns.COLUMNS
TIMING_COLUMNS = columns.TIMING_COLUMNS
EVENT_COLUMNS = ("t_vehicle_s", "kind", "detail")
BLOCK_ROWS = 10
"""Rows per block (80 ms at 125 Hz): what a crash can lose at most."""


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


def columns_path(log_path: str | Path) -> Path:
    """``flight.csv`` -> ``flight.columns`` (the rows in flight, :mod:`companion.logs.columns`)."""
    path = Path(log_path)
    return path.with_name(f"{path.stem}.columns")


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


def _put(row: NDArray[np.float64], span: slice, name: str, values: ArrayLike | None) -> None:
    """``values`` into ``row[span]`` (left NaN when None)."""
    if values is None:
        return
    try:
        row[span] = values
    except ValueError:
        n = span.stop - span.start
        got = np.asarray(values).size
        raise FlightLogError(f"{name} must have {n} entries, got {got}") from None


def _value(value: float | bool | None) -> float:
    return math.nan if value is None else float(value)


def fill_row(row: NDArray[np.float64], record: CycleRecord, log: LogColumns) -> None:
    """``record`` into a row of :data:`~companion.logs.columns.ROW` (pure but for the
    text codes ``log`` hands out); ``row`` is all NaN before."""
    r = record
    row[columns.T] = r.t_vehicle_s
    _put(row, columns.Q, "q", r.q)
    _put(row, columns.Q_DOT, "q_dot", r.q_dot)
    _put(row, columns.Q_DDOT, "q_ddot", r.q_ddot)
    _put(row, columns.Q_D, "q_d", r.q_d)
    if r.theta_hat is not None:
        _put(row, columns.THETA, "theta_hat", r.theta_hat)
        m2, m3 = row[columns.THETA.start], row[columns.THETA.start + 1]
        row[columns.LC] = m3 / m2 if m2 != 0.0 else math.nan
    row[columns.EXCITATION] = _value(r.theta_excitation)
    row[columns.SPREAD] = _value(r.theta_spread)
    row[columns.CONFIDENT] = _value(r.theta_confident)
    row[columns.FROZEN] = _value(r.theta_frozen)
    row[columns.THRUST_SCALE] = _value(r.thrust_scale_hat)
    _put(row, columns.TAU, "tau", r.tau)
    sp = r.setpoint
    if sp is not None:
        row[columns.SETPOINT] = (
            sp.roll_rad,
            sp.pitch_rad,
            sp.yaw_rad,
            sp.thrust_n,
            sp.thrust_relative,
            sp.tilt_saturated,
            sp.thrust_saturated,
        )
    _put(row, columns.SERVO_CMD, "servo_torque_cmd_n_m", r.servo_torque_cmd_n_m)
    _put(row, columns.SERVO_MEAS, "servo_torque_meas_n_m", r.servo_torque_meas_n_m)
    _put(row, columns.SERVO_POS, "servo_position_rad", r.servo_position_rad)
    row[columns.PERIOD] = _value(r.loop_period_ms)
    row[columns.MODE] = log.code(r.px4_mode)
    row[columns.ARMED] = _value(r.armed)
    row[columns.PHASE] = log.code(r.phase)
    row[columns.FAULTS] = log.code(";".join(r.faults))
    row[columns.T_WALL] = time.time() if r.t_wall_s is None else r.t_wall_s
    row[columns.SETPOINT_LATENCY] = _value(r.setpoint_latency_us)
    row[columns.CYCLE_LATENCY] = _value(r.cycle_latency_us)
    row[columns.SETPOINT_CPU] = _value(r.setpoint_cpu_us)


class FlightLogWriter:
    """Writes ``LOG.csv``, ``LOG.events.csv`` and ``LOG.timing.csv`` (see the module
    docstring), through ``LOG.columns`` in flight.

    Nothing is opened in the constructor; use ``with FlightLogWriter(path) as log`` or
    :meth:`open` / :meth:`close` (idempotent). A log is never overwritten: :meth:`open`
    raises :class:`FlightLogError` if any of the files exists.

    A cycle goes into the next row of :attr:`columns` (:meth:`write` from a
    :class:`CycleRecord`, or :meth:`row` and :meth:`commit` filled directly); a full block
    is written to ``LOG.columns`` by :meth:`flush`, in the cycle that fills it; the CSV
    files get their rows at :meth:`close`.

    Parameters
    ----------
    path : str or Path
        The cycle log; its directory must exist.
    block_rows : int
        Rows per block: the rows are written every this many cycles (and at each event).
    """

    def __init__(self, path: str | Path, block_rows: int = BLOCK_ROWS) -> None:
        if block_rows < 1:
            raise ValueError("block_rows must be at least 1")
        self.path = Path(path)
        self.events_path = events_path(self.path)
        self.timing_path = timing_path(self.path)
        self.columns_path = columns_path(self.path)
        self.columns = LogColumns(block_rows)
        self.rows = 0
        """Rows written or waiting in the block."""
        self._files: list[IO[str]] = []
        self._events: Any = None
        self._columns_file = ColumnsFile(self.columns_path)
        self._mode = 0.0
        self._phase = 0.0
        self._faults = 0.0
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
            self._columns_file.open()
        except FileExistsError as exc:
            self.close()
            raise FlightLogError(
                f"{exc.filename}: exists; a flight log is never overwritten"
            ) from None
        except OSError as exc:
            self.close()
            raise FlightLogError(f"{exc.filename}: cannot write: {exc.strerror}") from None
        self._events = csv.writer(self._files[1])
        csv.writer(self._files[0]).writerow(COLUMNS)
        self._events.writerow(EVENT_COLUMNS)
        csv.writer(self._files[2]).writerow(TIMING_COLUMNS)
        for file in self._files:
            file.flush()

    def write(self, record: CycleRecord) -> None:
        """Append one cycle; writes ``mode`` / ``phase`` / ``fault`` events on changes."""
        fill_row(self.row(), record, self.columns)
        self.commit()

    def row(self) -> NDArray[np.float64]:
        """The row of the next cycle (all NaN), to fill and :meth:`commit`."""
        if self._events is None:
            raise FlightLogError(f"{self.path}: the log is not open")
        return self.columns.next_row()

    def code(self, text: str) -> float:
        """The code of ``text`` in a text column of :meth:`row`."""
        return self.columns.code(text)

    def commit(self) -> None:
        """The row from :meth:`row` is filled: write the events it brings (a changed
        mode, phase or fault set), and the block when it is full."""
        log = self.columns
        self.rows += 1
        row = log.block[log.n - 1]
        mode, phase, faults = row[columns.MODE], row[columns.PHASE], row[columns.FAULTS]
        if mode == self._mode and phase == self._phase and faults == self._faults:
            if log.full:
                self.flush()
            return
        t = float(row[columns.T])
        texts = log.texts
        if mode != self._mode:
            self.event("mode", f"{texts[int(self._mode)]}->{texts[int(mode)]}", t)
            self._mode = mode
        if phase != self._phase:
            self.event("phase", f"{texts[int(self._phase)]}->{texts[int(phase)]}", t)
            self._phase = phase
        if faults != self._faults:
            old = set(filter(None, texts[int(self._faults)].split(";")))
            new = set(filter(None, texts[int(faults)].split(";")))
            for name in sorted(new - old):
                self.event("fault", name, t)
            for name in sorted(old - new):
                self.event("fault_cleared", name, t)
            self._faults = faults

    def flush(self) -> None:
        """Write the rows of the block and hand them to the OS."""
        if not self._files:
            return
        self.write_block(self.columns.take())

    def write_block(self, rows: NDArray[np.float64]) -> None:
        """Write ``rows`` (taken from the block) to ``LOG.columns``."""
        self._columns_file.write(rows, self.columns.texts)

    def event(self, kind: str, detail: str, t_vehicle_s: float) -> None:
        """Append an event after the rows before it (written at once: events are rare and
        matter after a crash)."""
        if self._events is None:
            raise FlightLogError(f"{self.path}: the log is not open")
        self.flush()
        self._events.writerow((_num(t_vehicle_s), kind, detail))
        self._files[1].flush()

    def close(self) -> None:
        """Write the block, the CSV files' rows from ``LOG.columns``, fsync, close, and
        remove ``LOG.columns`` (idempotent)."""
        self._closed = True
        files, self._files = self._files, []
        self._events = None
        try:
            if len(files) == 3 and self.columns_path.exists():
                self.write_block(self.columns.take())
                self._columns_file.close()
                rows, texts, _ = read_columns(self.columns_path)
                write_csv(rows, texts, files[0], files[2])
        finally:
            self._columns_file.close()
            for f in files:
                f.flush()
                os.fsync(f.fileno())
                f.close()
        if len(files) == 3:
            self.columns_path.unlink(missing_ok=True)


def export_columns(path: str | Path) -> int:
    """Write ``LOG.csv`` and ``LOG.timing.csv`` from ``LOG.columns`` (``path``), left by a
    flight that did not close its log (a crash, a ``kill -9``, a power cut): its rows up to
    the last block written; the number of rows. A CSV file that holds rows already is kept
    (:class:`FlightLogError`); one with its header only (the crashed flight's) is replaced.
    ``LOG.columns`` is kept.
    """
    path = Path(path)
    log_path = path.with_suffix(".csv")
    try:
        rows, texts, _ = read_columns(path)
    except ColumnsError as exc:
        raise FlightLogError(str(exc)) from None
    targets = (log_path, timing_path(log_path))
    for target in targets:
        if target.exists() and target.stat().st_size > 0:
            with open(target, "rb") as f:
                if len(f.read(MAX_ROW_BYTES).splitlines()) > 1:
                    raise FlightLogError(f"{target}: holds rows already; not replaced")
    tmp = [t.with_name(t.name + ".tmp") for t in targets]
    try:
        with (
            open(tmp[0], "w", newline="", encoding="utf-8") as main,
            open(tmp[1], "w", newline="", encoding="utf-8") as timing,
        ):
            csv.writer(main).writerow(COLUMNS)
            csv.writer(timing).writerow(TIMING_COLUMNS)
            write_csv(rows, texts, main, timing)
        for t, target in zip(tmp, targets, strict=True):
            fsync(t)
            os.replace(t, target)
    finally:
        for t in tmp:
            t.unlink(missing_ok=True)
    return len(rows)


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

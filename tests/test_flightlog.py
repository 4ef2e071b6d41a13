"""Flight log: write cycles and events, read them back exactly; clear errors for bad files."""

import csv
import math
import signal
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from companion.cli.main import app
from companion.control.setpoints import AttitudeThrustSetpoint
from companion.logs.columns import read_columns
from companion.logs.flightlog import (
    COLUMNS,
    TIMING_COLUMNS,
    CycleRecord,
    FlightLogError,
    FlightLogWriter,
    columns_path,
    events_path,
    export_columns,
    read_flight_log,
    timing_path,
)


def record(i, mode="POSCTL", phase="takeoff", faults=()):
    rng = np.random.default_rng(i)
    return CycleRecord(
        t_vehicle_s=10.0 + 0.004 * i,
        t_wall_s=1.7e9 + 0.004 * i,
        q=rng.normal(size=8),
        q_dot=rng.normal(size=8),
        q_ddot=rng.normal(size=8),
        q_d=rng.normal(size=8),
        theta_hat=(0.35, 0.035, 0.0035),
        theta_excitation=0.02,
        theta_spread=float("inf") if i == 0 else 0.01,
        theta_confident=i > 2,
        theta_frozen=False,
        thrust_scale_hat=0.93,
        tau=rng.normal(size=8),
        setpoint=AttitudeThrustSetpoint(0.01, -0.02, 0.3, 14.2, 0.47, False, i == 4),
        servo_torque_cmd_n_m=(0.1, -0.2),
        servo_torque_meas_n_m=(0.09, -0.21),
        servo_position_rad=(-1.5, 0.3),
        loop_period_ms=4.0 + 0.1 * i,
        setpoint_latency_us=None if i == 1 else 900.0 + i,
        cycle_latency_us=1100.0 + i,
        setpoint_cpu_us=None if i == 1 else 700.0 + i,
        px4_mode=mode,
        armed=True,
        phase=phase,
        faults=faults,
    )


def test_round_trip_is_exact(tmp_path):
    path = tmp_path / "flight.csv"
    records = [record(i) for i in range(5)]
    with FlightLogWriter(path, block_rows=2) as log:
        for r in records:
            log.write(r)
    out = read_flight_log(path)
    assert len(out) == 5
    assert tuple(out.columns) == (*COLUMNS, *TIMING_COLUMNS[1:])
    q = np.stack([out[c] for c in COLUMNS if c.startswith("q_")], axis=1)
    np.testing.assert_array_equal(q, np.stack([r.q for r in records]))
    tau = np.stack([out[c] for c in COLUMNS if c.startswith("tau_")], axis=1)
    np.testing.assert_array_equal(tau, np.stack([r.tau for r in records]))
    np.testing.assert_array_equal(out["t_vehicle_s"], [r.t_vehicle_s for r in records])
    assert out["theta_hat_lc_m"] == pytest.approx([0.1] * 5)
    assert out["theta_spread"][0] == math.inf
    np.testing.assert_array_equal(out["theta_confident"], [0, 0, 0, 1, 1])
    np.testing.assert_array_equal(out["sp_thrust_saturated"], [0, 0, 0, 0, 1])
    assert out["thrust_rel"] == pytest.approx([0.47] * 5)
    assert list(out["px4_mode"]) == ["POSCTL"] * 5
    # The cycle's timing; no setpoint sent in cycle 1 (an empty cell, NaN).
    assert out["loop_period_ms"] == pytest.approx([4.0, 4.1, 4.2, 4.3, 4.4])
    assert math.isnan(out["setpoint_latency_us"][1]) and out["setpoint_latency_us"][2] == 902.0
    np.testing.assert_array_equal(out["cycle_latency_us"], [1100.0, 1101.0, 1102.0, 1103.0, 1104.0])
    assert math.isnan(out["setpoint_cpu_us"][1]) and out["setpoint_cpu_us"][4] == 704.0
    assert out["t_wall_s"][4] == 1.7e9 + 0.016
    assert out["thrust_scale_hat"] == pytest.approx([0.93] * 5)


def test_the_wall_clock_is_kept_apart_from_the_flight(tmp_path):
    """Two logs of the same flight measured at other wall times: ``LOG.csv`` and the
    events are the same bytes, only ``LOG.timing.csv`` differs."""
    logs = []
    for n, offset_s in enumerate((0.0, 3600.0)):
        path = tmp_path / f"run{n}" / "flight.csv"
        path.parent.mkdir()
        with FlightLogWriter(path) as log:
            for i in range(5):
                r = record(i)
                log.write(replace(r, t_wall_s=r.t_wall_s + offset_s, cycle_latency_us=1.0 + n))
            log.event("gripper", "close", 10.02)
        logs.append(path)
    a, b = logs
    assert a.read_bytes() == b.read_bytes()
    assert events_path(a).read_bytes() == events_path(b).read_bytes()
    assert timing_path(a).read_bytes() != timing_path(b).read_bytes()
    assert "t_wall_s" not in a.read_text().splitlines()[0]
    timing_path(a).unlink()  # a log without its timing reads with NaN there
    assert np.isnan(read_flight_log(a)["cycle_latency_us"]).all()


def test_a_log_written_before_the_thrust_scale_column_reads_with_nan(tmp_path):
    """Logs of earlier versions lack ``thrust_scale_hat``: they still read (and plot)."""
    path = tmp_path / "flight.csv"
    with FlightLogWriter(path) as log:
        for i in range(3):
            log.write(record(i))
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    drop = rows[0].index("thrust_scale_hat")
    with path.open("w", newline="") as f:
        csv.writer(f).writerows([r[:drop] + r[drop + 1 :] for r in rows])
    out = read_flight_log(path)
    assert tuple(out.columns) == (*COLUMNS, *TIMING_COLUMNS[1:])
    assert np.isnan(out["thrust_scale_hat"]).all() and len(out["thrust_scale_hat"]) == 3
    assert out["thrust_rel"] == pytest.approx([0.47] * 3)


def test_header_is_one_row_with_units_and_pandas_style(tmp_path):
    path = tmp_path / "flight.csv"
    with FlightLogWriter(path) as log:
        log.write(record(0))
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0] == list(COLUMNS)
    assert len(rows) == 2 and len(rows[1]) == len(COLUMNS)
    for name in ("q_x_m", "qdot_phi_rad_s", "qddot_eta2_rad_s2", "theta_hat_m2_kg",
                 "tau_z_n", "tau_eta1_n_m", "thrust_rel", "servo_tau_meas_eta2_n_m"):  # fmt: skip
        assert name in COLUMNS


def test_missing_parts_are_empty_cells_read_as_nan(tmp_path):
    path = tmp_path / "flight.csv"
    with FlightLogWriter(path) as log:
        log.write(CycleRecord(t_vehicle_s=1.0, q=np.zeros(8)))
    out = read_flight_log(path)
    assert out["q_x_m"][0] == 0.0
    assert np.isnan(out["tau_x_n"][0]) and np.isnan(out["theta_hat_lc_m"][0])
    assert np.isnan(out["armed"][0])
    assert out["faults"][0] == ""
    assert path.read_text().splitlines()[1].endswith(",,,,")  # mode, armed, phase, faults


def test_mode_phase_and_fault_changes_become_events(tmp_path):
    path = tmp_path / "flight.csv"
    with FlightLogWriter(path) as log:
        log.write(record(0, mode="POSCTL"))
        log.write(record(1, mode="OFFBOARD", phase="grasp"))
        log.write(record(2, mode="OFFBOARD", phase="grasp", faults=("servo_timeout",)))
        log.write(record(3, mode="LAND", phase="grasp", faults=("servo_timeout", "tilt_sat")))
        log.write(record(4, mode="LAND", phase="grasp"))
        log.event("note", "operator abort, with a comma", 10.02)
    events = read_flight_log(path).events
    got = list(zip(events["kind"], events["detail"], strict=True))
    assert got == [
        ("mode", "->POSCTL"),
        ("phase", "->takeoff"),
        ("mode", "POSCTL->OFFBOARD"),
        ("phase", "takeoff->grasp"),
        ("fault", "servo_timeout"),
        ("mode", "OFFBOARD->LAND"),
        ("fault", "tilt_sat"),
        ("fault_cleared", "servo_timeout"),
        ("fault_cleared", "tilt_sat"),
        ("note", "operator abort, with a comma"),
    ]
    assert events["t_vehicle_s"][2] == pytest.approx(10.004)
    assert read_flight_log(path)["faults"][3] == "servo_timeout;tilt_sat"


def test_rows_reach_the_columns_a_block_at_a_time_and_the_csv_at_close(tmp_path):
    path = tmp_path / "flight.csv"
    log = FlightLogWriter(path, block_rows=3)
    log.open()
    log.write(record(0))
    assert len(read_columns(columns_path(path))[0]) == 1  # its events (mode, phase) wrote it
    for i in range(1, 3):
        log.write(record(i))
    assert len(read_columns(columns_path(path))[0]) == 1  # in the block
    log.write(record(3))
    assert len(read_columns(columns_path(path))[0]) == 4  # the full block, still open
    log.write(record(4))
    log.event("note", "an event writes the rows before it", 10.02)
    assert len(read_columns(columns_path(path))[0]) == 5
    assert len(read_flight_log(path)) == 0  # the CSV's header: its rows come at the close
    log.close()
    log.close()
    assert len(read_flight_log(path)) == 5
    assert not columns_path(path).exists()
    with pytest.raises(FlightLogError, match="not open"):
        log.write(record(5))


def test_bad_records_and_paths(tmp_path):
    with pytest.raises(FlightLogError, match="cannot write"):
        FlightLogWriter(tmp_path / "no" / "dir.csv").open()
    with FlightLogWriter(tmp_path / "f.csv") as log, pytest.raises(FlightLogError, match="q must"):
        log.write(CycleRecord(t_vehicle_s=0.0, q=np.zeros(7)))
    with pytest.raises(ValueError):
        FlightLogWriter(tmp_path / "g.csv", block_rows=0)


KILLED_WRITER = """
import os, signal, sys
sys.path.insert(0, {tests!r})
from test_flightlog import record
from companion.logs.flightlog import FlightLogWriter
log = FlightLogWriter({path!r}, block_rows=4)
log.open()
for i in range(10):
    log.write(record(i))
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_a_kill_9_loses_at_most_the_last_block(tmp_path):
    """A writer killed without a chance to close: ``companion log export`` writes the CSV
    from the columns; the rows written before read back as written, only the rows of the
    last, unwritten block are lost (the first row went out at once with its events, then
    two blocks of 4, and the last row was in the block)."""
    path = tmp_path / "flight.csv"
    script = KILLED_WRITER.format(tests=str(Path(__file__).parent), path=str(path))
    done = subprocess.run([sys.executable, "-c", script], check=False, timeout=60)
    assert done.returncode == -signal.SIGKILL
    assert len(read_flight_log(path)) == 0  # the header the flight wrote at its start
    result = CliRunner().invoke(app, ["log", "export", str(columns_path(path))])
    assert result.exit_code == 0, result.output
    assert "9 rows" in result.output
    out = read_flight_log(path)
    assert len(out) == 9 and out.warnings == ()
    np.testing.assert_array_equal(out["q_x_m"], [record(i).q[0] for i in range(9)])
    np.testing.assert_array_equal(out["cycle_latency_us"], [1100.0 + i for i in range(9)])
    assert [k for k in out.events["kind"]] == ["mode", "phase"]
    with pytest.raises(FlightLogError, match="holds rows already"):
        export_columns(columns_path(path))  # what was exported is not written over


def test_a_columns_file_cut_in_a_record_reads_up_to_the_cut(tmp_path):
    path = tmp_path / "flight.csv"
    log = FlightLogWriter(path, block_rows=2)
    log.open()
    for i in range(5):
        log.write(record(i))
    cut = tmp_path / "cut.columns"
    data = columns_path(path).read_bytes()
    cut.write_bytes(data[:-7])  # the second block of two, cut
    log.close()
    rows, texts, warnings = read_columns(cut)
    assert len(rows) == 3 and "POSCTL" in texts and "cut short" in warnings[0]
    (tmp_path / "x.columns").write_bytes(b"t_vehicle_s\n")
    with pytest.raises(FlightLogError, match="not a flight columns file"):
        export_columns(tmp_path / "x.columns")


def test_a_number_that_is_not_one_is_an_empty_cell(tmp_path):
    path = tmp_path / "flight.csv"
    with FlightLogWriter(path) as log:
        log.write(replace(record(0), servo_torque_meas_n_m=(math.nan, 0.5)))
    row = path.read_text().splitlines()[1].split(",")
    assert row[COLUMNS.index("servo_tau_meas_eta1_n_m")] == ""
    assert row[COLUMNS.index("servo_tau_meas_eta2_n_m")] == "0.5"
    assert np.isnan(read_flight_log(path)["servo_tau_meas_eta1_n_m"][0])


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        ("", "empty file"),
        ("a,b,c\n1,2,3\n", "not a flight log header"),
        (",".join(COLUMNS) + "\n1,2\n", "line 2: 2 cells"),
        (",".join(COLUMNS) + "\n" + ",".join(["x"] * len(COLUMNS)) + "\n", "is not a number"),
    ],
)
def test_malformed_logs_raise_with_file_and_line(tmp_path, content, reason):
    path = tmp_path / "bad.csv"
    path.write_text(content)
    with pytest.raises(FlightLogError, match=reason) as info:
        read_flight_log(path)
    assert str(path) in str(info.value)


def test_missing_log_and_missing_events_file(tmp_path):
    with pytest.raises(FlightLogError, match="cannot read"):
        read_flight_log(tmp_path / "absent.csv")
    path = tmp_path / "flight.csv"
    with FlightLogWriter(path) as log:
        log.write(record(0))
    events_path(path).unlink()
    assert len(read_flight_log(path).events["kind"]) == 0
    assert events_path(path).name == "flight.events.csv"

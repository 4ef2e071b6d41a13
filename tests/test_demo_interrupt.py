"""Ctrl-C during ``sitl demo``: one line saying it was stopped, at which vehicle time and
where the partial log is; exit status 130; ``summary.json`` written with ``outcome =
"interrupted"``; the flight log readable to its last row. On simulated time (the lockstep
loop cancels the mission as ``asyncio.run`` does) and on the wall clock (the simulator in
its own session, so that the arm's safe state still reaches its servos)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from companion.logs.columns import read_columns
from companion.logs.flightlog import read_flight_log


def _demo_stopped_in_flight(out: Path, *clock: str) -> subprocess.CompletedProcess:
    """Start ``sitl demo`` into ``out``, send SIGINT once its flight log holds 200 rows
    (the vehicle in the air; in flight the rows are in ``flight.columns``, ``flight.csv``
    gets them at the close), and wait for it (a hang fails after 120 s)."""
    process = subprocess.Popen(
        [sys.executable, "-c", "from sitl.cli import main; main()", "demo", "--out", str(out),
         *clock],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # SIGINT as in a terminal, even where the suite runs as a background job (the shell
        # then ignores SIGINT for its children, and Python keeps an ignored SIGINT ignored)
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    columns = out / "flight.columns"
    deadline = time.monotonic() + 300.0
    try:
        while not (columns.exists() and len(read_columns(columns)[0]) > 200):
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, "the flight never started"
            time.sleep(0.2)
        process.send_signal(signal.SIGINT)
        stdout, stderr = process.communicate(timeout=120.0)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    return subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr)


def _stopped_cleanly(done: subprocess.CompletedProcess, out: Path) -> None:
    assert done.returncode == 130, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("stopped: interrupted at t = ") and str(out) in lines[0]
    assert "Traceback" not in done.stdout + done.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "interrupted" and not summary["completed"]
    assert summary["failure"].startswith("MissionInterrupted: interrupted at t = ")
    assert len(read_flight_log(out / "flight.csv")) > 200  # written at the close
    assert not (out / "flight.columns").exists()


def test_ctrl_c_on_simulated_time_stops_in_one_line_with_a_summary(tmp_path):
    out = tmp_path / "demo"
    _stopped_cleanly(_demo_stopped_in_flight(out, "--clock", "virtual"), out)


@pytest.mark.slow
def test_ctrl_c_on_the_wall_clock_stops_in_one_line_with_a_summary(tmp_path):
    out = tmp_path / "demo"
    done = _demo_stopped_in_flight(out, "--speed", "3")
    _stopped_cleanly(done, out)
    assert "safe state" not in done.stdout + done.stderr  # the simulator's bus was still up

"""Campaigns: a spec's mistakes are one line each before anything flies; the designs are
seeded and stratified; the shipped specs expand to the flights they promise; and a tiny
campaign on two worker processes records every flight once, with figures within absolute
bounds, a crashed flight as an error with a replay command that reproduces it, a report,
and a rerun that flies exactly the flights missing from the table; the shipped smoke spec
gives the same table on the local and the Ray engine.

The tiny campaign flies three pickups in all (two, then one again after its row is
removed); its other two flights crash at once (a joint gain too high for the control
rate), before the vehicle takes off. The smoke spec flies four, on each engine.
"""

from __future__ import annotations

import json
import os
import shlex
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner, Result

from companion.config import read_toml
from sitl.campaign.design import sample_ranges, unit_design
from sitl.campaign.flights import (
    expand,
    replay_command,
    replay_toml,
    scenario_document,
    scenario_of,
)
from sitl.campaign.report import write_report
from sitl.campaign.spec import load_spec
from sitl.campaign.store import TIMING_COLUMNS
from sitl.cli import app as sitl_app
from sitl.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGNS = ROOT / "configs" / "campaigns"
PICKUP = ROOT / "configs" / "sitl_pickup.toml"


def sitl(*args: str | Path) -> Result:
    return CliRunner().invoke(sitl_app, [str(a) for a in args])


def write_spec(tmp_path: Path, body: str, name: str = "spec.toml") -> Path:
    path = tmp_path / name
    path.write_text(f'name = "tiny"\nscenario = "{PICKUP}"\n' + body)
    return path


# --- the spec's mistakes ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("body", "words"),
    [
        ('controlers = ["passivity"]\n', ("controlers", "unknown key", "'controllers'")),
        (
            '[axes]\n"payload.mas_kg" = { values = [0.2] }\n',
            (
                'axes."payload.mas_kg"',
                "no scenario key 'mas_kg' in [payload]",
                "did you mean 'payload.mass_kg'",
            ),
        ),
        (
            '[set]\n"plant.battery.start_charg" = 0.5\n',
            ("did you mean 'plant.battery.start_charge'",),
        ),
        (
            '[axes]\n"world.payload_position_m[0].x" = { values = [1.0] }\n',
            ("holds a value, not a table",),
        ),
        ('[axes]\n"payload.mass_kg" = { range = [0.4, 0.1] }\n', ("low must be below high",)),
        (
            '[design]\nsamples = 4\n[axes]\n"payload.position_m" = { range = [0.1, 0.3] }\n',
            ("payload.position_m", "beyond link 2"),
        ),
        ('[[faults]]\nkind = "link_cut"\nat_s = 20.0\n', ("link_cut needs duration_s",)),
        (
            '[[faults]]\nkind = "link_cut"\nat_phase = "grab"\nduration_s = 2.0\n',
            ("at_phase must be one of takeoff, to_object", "'grab'"),
        ),
        (
            '[[faults]]\nkind = "link_cut"\nat_s = 2.0\nat_phase = "grasp"\nduration_s = 2.0\n',
            ("either at_s or at_phase",),
        ),
        (
            '[[faults]]\nkind = "servo_silent"\nservo_id = 2\nat_s = 2.0\noffset_s = 1.0\n',
            ("offset_s is the time into at_phase",),
        ),
        (
            '[[faults]]\nkind = "servo_error"\nservo_id = 1\nat_phase = "lift"\n',
            ("servo_error needs error",),
        ),
        (
            '[[faults]]\nkind = "servo_error"\nservo_id = 1\nerror = "melted"\nat_s = 9.0\n',
            ("error", "'overload'"),
        ),
        ('controllers = ["passivity", "pid"]\n', ("controllers",)),
        (
            "[bounds.passivity]\nmass_eror_pct = 3.0\n",
            ("bounds.passivity.mass_eror_pct", "'mass_error_pct'"),
        ),
        ("[bounds.passivity]\nmass_error_pct = -3.0\n", ("greater than 0",)),
        ('autopilots = ["px5"]\n', ("autopilots", "'imitation' or 'px4'")),
        (
            'autopilots = ["px4"]\n[[faults]]\nkind = "link_loss"\nat_s = 20.0\nduration_s = 2.0\n'
            "drop_fraction = 0.3\n",
            ("link_loss and bus_corruption fly on the imitation only",),
        ),
    ],
)
def test_a_spec_mistake_is_one_line_naming_the_key_and_nothing_flies(tmp_path, body, words):
    result = sitl("campaign", write_spec(tmp_path, body), "--out", tmp_path / "out")
    assert isinstance(result.exception, SystemExit), result.exception
    assert result.exit_code == 2, (result.stdout, result.stderr)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.stderr + result.stdout
    for word in words:
        assert word in lines[0], lines[0]
    assert not (tmp_path / "out").exists()


def test_a_px4_spec_without_a_px4_build_is_one_line_and_nothing_flies(tmp_path, monkeypatch):
    monkeypatch.delenv("PX4_SITL_DIR", raising=False)
    spec = write_spec(tmp_path, 'autopilots = ["px4"]\n')
    for extra in ((), ("--px4-dir", str(tmp_path))):
        result = sitl("campaign", spec, "--out", tmp_path / "out", *extra)
        assert result.exit_code == 2, (result.stdout, result.stderr)
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
        assert "Traceback" not in result.stderr + result.stdout
    assert "--px4-dir" in sitl("campaign", spec, "--out", tmp_path / "out").stderr
    assert not (tmp_path / "out").exists()


def test_a_mixed_spec_replays_its_imitation_flights_without_a_px4_build(tmp_path, monkeypatch):
    """Only a px4 flight needs the build: the imitation's replay flies (here a draw whose
    joint gain is too high for the loop, which fails at once with its reason), the px4
    flight's replay is the one line asking for the build."""
    monkeypatch.delenv("PX4_SITL_DIR", raising=False)
    spec = write_spec(
        tmp_path,
        'autopilots = ["imitation", "px4"]\n'
        '[set]\n"world.payload_position_m" = [0.8, 0.0, 0.05]\n'
        '[axes]\n"controller.k[6]" = { values = [500.0] }\n',
    )
    imitation, px4 = expand(load_spec(spec), spec)
    out = tmp_path / "out"
    flown = sitl("campaign", spec, "--out", out, "--replay", imitation.flight_id)
    assert flown.exit_code == 1, (flown.stdout, flown.stderr)
    assert "too long for the velocity gains" in flown.stderr
    assert "pass --px4-dir" not in flown.stderr
    refused = sitl("campaign", spec, "--out", out, "--replay", px4.flight_id)
    assert refused.exit_code == 2 and "pass --px4-dir DIR or set PX4_SITL_DIR" in refused.stderr


def test_px4_flights_are_their_own_pairs_and_leave_the_imitations_ids_as_they_were(tmp_path):
    """The autopilot is part of a px4 flight's identity (its own id and pair); the
    imitation's ids do not name it, so tables written before autopilots came stay valid."""
    one = expand(load_spec(write_spec(tmp_path, "", "one.toml")), tmp_path / "one.toml")
    both = write_spec(tmp_path, 'autopilots = ["imitation", "px4"]\n', "both.toml")
    two = expand(load_spec(both), both)
    assert [f.autopilot for f in two] == ["imitation", "px4"]
    assert two[0].flight_id == one[0].flight_id and two[0].pair_id == one[0].pair_id
    assert two[1].flight_id != two[0].flight_id and two[1].pair_id != two[0].pair_id
    replay = replay_command(two[1], tmp_path / "out", both)
    assert replay.startswith("sitl demo --autopilot px4 --speed validated --config ")


def test_a_completed_flight_beyond_its_controllers_bounds_is_named_with_the_figure():
    spec = load_spec(CAMPAIGNS / "envelope.toml")
    row = {"controller": "passivity", "completed": 1, "mass_error_pct": -42.06}
    row |= {"com_error_pct": 4.9, "placement_error_m": 0.01}
    assert spec.outside_bounds(row) == ["mass_error_pct -42.06 (bound 3)"]
    assert spec.outside_bounds(row | {"mass_error_pct": 2.9}) == []
    assert spec.outside_bounds(row | {"completed": 0}) == []  # a failure of its own
    assert spec.outside_bounds(row | {"controller": "nonadaptive"}) == []  # no bounds
    assert spec.outside_bounds(row | {"mass_error_pct": None}) == []  # not measured


def test_a_broken_estimator_is_caught_and_its_replay_fails_the_same_way(run_sitl, tmp_path):
    """The shipped broken spec (the estimate frozen at the empty arm): the flight fails, the
    report lists it with its command, and that command alone fails the same way."""
    out = tmp_path / "broken"
    spec = CAMPAIGNS / "broken_estimator.toml"
    done = run_sitl("campaign", str(spec), "--out", str(out), "--limit", "1")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "1 did not complete" in done.stdout, done.stdout
    (row,) = table(out).values()
    assert row["status"] == "ok" and row["completed"] == 0
    assert row["replay"].startswith("sitl demo --clock virtual --config ")
    report = (out / "report.html").read_text()
    assert row["flight_id"] in report and row["replay"] in report
    again = run_sitl(*shlex.split(row["replay"])[1:])
    cause = row["failure"].split(": ", 1)[1].split(";")[0]
    assert again.returncode == 1, again.stdout + again.stderr
    assert f"mission failed: {cause}" in again.stderr, (cause, again.stderr)


# --- designs and expansion ----------------------------------------------------------------


def test_the_latin_hypercube_puts_one_draw_in_each_slice_of_every_axis_from_its_seed():
    u = unit_design("latin_hypercube", 40, 3, seed=5)
    assert u.shape == (40, 3) and np.all((u >= 0.0) & (u < 1.0))
    for axis in range(3):
        assert sorted(np.floor(u[:, axis] * 40).astype(int)) == list(range(40))
    np.testing.assert_array_equal(u, unit_design("latin_hypercube", 40, 3, seed=5))
    assert not np.array_equal(u, unit_design("latin_hypercube", 40, 3, seed=6))
    x = sample_ranges("random", 200, [(0.1, 0.45), (-2.0, -1.0)], seed=1)
    assert np.all((x[:, 0] >= 0.1) & (x[:, 0] < 0.45) & (x[:, 1] >= -2.0) & (x[:, 1] < -1.0))


def test_the_shipped_specs_expand_to_their_flights_in_pairs_with_stable_ids():
    for name, low, high in (("smoke", 4, 4), ("envelope", 300, 10_000)):
        path = CAMPAIGNS / f"{name}.toml"
        flights = expand(load_spec(path), path)
        assert low <= len(flights) <= high, (name, len(flights))
        ids = [f.flight_id for f in flights]
        assert len(set(ids)) == len(ids)
        assert ids == [f.flight_id for f in expand(load_spec(path), path)]
        pairs: dict[str, list] = {}
        for f in flights:
            pairs.setdefault(f.pair_id, []).append(f)
        for pair in pairs.values():
            assert sorted(f.controller for f in pair) == ["nonadaptive", "passivity"]
            assert len({(f.seed, f.settings, f.place_at_m) for f in pair}) == 1
    envelope = expand(load_spec(CAMPAIGNS / "envelope.toml"), CAMPAIGNS / "envelope.toml")
    masses = [dict(f.settings)["payload.mass_kg"] for f in envelope]
    assert 0.08 <= min(masses) < 0.09 and 0.47 < max(masses) <= 0.48
    # The envelope's guard in the suite: 32 adaptive draws over the envelope's own axes.
    axes = load_spec(CAMPAIGNS / "envelope.toml").axes
    guard = load_spec(CAMPAIGNS / "envelope_sample.toml")
    assert guard.axes == axes and guard.controllers == ("passivity",)
    assert len(expand(guard, CAMPAIGNS / "envelope_sample.toml")) == 32
    # The PX4 sample: 20 adaptive flights on PX4 over the envelope's axes but the battery
    # (PX4 reports its own, held full).
    sample_path = CAMPAIGNS / "envelope_px4.toml"
    sample = load_spec(sample_path)
    assert sample.axes == {k: v for k, v in axes.items() if not k.startswith("plant.battery")}
    flights = expand(sample, sample_path)
    assert len(flights) == 20 and {(f.autopilot, f.controller) for f in flights} == {
        ("px4", "passivity")
    }
    # The baseline sample: 10 draws of the same axes, each flown by the adaptive controller
    # and by PX4's own position control on PX4, on the same seed.
    baseline_path = CAMPAIGNS / "envelope_px4_baseline.toml"
    baseline = load_spec(baseline_path)
    assert baseline.axes == sample.axes
    pairs = {}
    for f in expand(baseline, baseline_path):
        pairs.setdefault(f.pair_id, []).append(f)
    assert len(pairs) == 10
    for pair in pairs.values():
        assert sorted((f.autopilot, f.controller) for f in pair) == [
            ("px4", "passivity"), ("px4", "px4_position")
        ]  # fmt: skip
        assert len({(f.seed, f.settings, f.place_at_m) for f in pair}) == 1


def test_the_replay_scenario_file_is_the_scenario_each_flight_flew(tmp_path):
    spec = write_spec(
        tmp_path,
        """
[design]
samples = 3
[set]
"plant.battery.capacity_ah" = 4.0
[axes]
"payload.mass_kg" = { range = [0.10, 0.45] }
"plant.battery.start_charge" = { range = [0.3, 1.0] }
"world.payload_position_m[1]" = { values = [0, 1] }
"plant.wind_m_s[0]" = { range = [-3.0, 3.0] }
[[faults]]
kind = "payload_slip"
after_grasp_s = 2.5
""",
    )
    flights = expand(load_spec(spec), spec)
    assert len(flights) == 6
    base, text = read_toml(PICKUP), PICKUP.read_text()
    for flight in flights:
        path = tmp_path / f"{flight.flight_id}.toml"
        path.write_text(replay_toml(flight, text))
        flown = scenario_of(flight, scenario_document(flight, base))
        assert load_scenario(path) == flown
        assert flown.world is not None and flown.world.payload_slip is not None
        assert flown.plant.battery is not None and flown.plant.battery.capacity_ah == 4.0
        east, north, up = flown.plant.wind_m_s
        assert -3.0 <= east <= 3.0 and east != 0.0 and north == up == 0.0
        assert east == dict(flight.settings)["plant.wind_m_s[0]"]


# --- a tiny campaign on two workers ---------------------------------------------------------

TINY = """
controllers = ["passivity", "nonadaptive"]
[set]
"world.payload_position_m" = [0.8, 0.0, 0.05]
[axes]
"controller.k[6]" = { values = [0.15, 500.0] }
"""
"""Two draws, each flown by both controllers: the shoulder's gain of the scenario (0.15)
flies; 500 is far too high for the 250 Hz loop and the flight refuses to start."""


def table(out: Path) -> dict[str, dict]:
    with sqlite3.connect(out / "results.sqlite") as db:
        cursor = db.execute("SELECT * FROM flights")
        names = [d[0] for d in cursor.description]
        rows = [dict(zip(names, r, strict=True)) for r in cursor]
    by_id = {r["flight_id"]: r for r in rows}
    assert len(by_id) == len(rows), "a flight recorded twice"
    return by_id


def test_a_tiny_campaign_records_every_flight_once_and_a_rerun_flies_only_the_missing(
    run_sitl, tmp_path
):
    """Every flight once, within absolute figures, errors with their replay; a rerun flies
    only the missing."""
    spec = write_spec(tmp_path, TINY)
    out = tmp_path / "out"
    done = run_sitl("campaign", str(spec), "--out", str(out), "--workers", "2")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "4 to fly on 2 workers" in done.stdout
    assert "campaign: 4/4 done" in done.stderr
    flights = {f.flight_id: f for f in expand(load_spec(spec), spec)}
    rows = table(out)
    assert rows.keys() == flights.keys()
    flown = {r["controller"]: r for r in rows.values() if r["controller.k[6]"] == 0.15}
    crashed = [r for r in rows.values() if r["controller.k[6]"] == 500.0]

    # The adaptive controller's flight: placed, the payload learnt, within absolute bounds.
    good = flown["passivity"]
    assert good["status"] == "ok" and good["completed"] == 1 and good["outcome"] == "completed"
    assert abs(good["mass_error_pct"]) < 10.0 and abs(good["com_error_pct"]) < 15.0
    assert good["true_mass_kg"] == 0.25 and good["placement_error_m"] < 0.10
    assert 0.0 < good["carry_rms_m"] < 0.04 and good["carry_rms_m"] <= good["carry_max_error_m"]
    assert 0.0 < good["max_tilt_deg"] < 15.0 and good["control_cycles"] > 1000
    assert 30.0 < good["sim_s"] < 300.0 and good["wall_s"] > 0.0 and good["cpu_s"] > 0.0
    assert good["version"] and json.loads(good["faults"]) == [] and good["replay"] is None
    # Its pair: the same draw and seed, the non-adaptive controller carrying worse.
    base = flown["nonadaptive"]
    assert base["status"] == "ok" and base["pair_id"] == good["pair_id"]
    assert base["seed"] == good["seed"]
    if base["carry_rms_m"] is not None:
        assert good["carry_rms_m"] < base["carry_rms_m"]

    # The crashed flights: errors with their traceback and a replay command that fails alike.
    assert len(crashed) == 2
    for row in crashed:
        assert row["status"] == "error" and "Traceback" in row["error"]
        assert "UsageError" in row["error"] and row["completed"] is None
        assert row["replay"].startswith("sitl demo --clock virtual --config ")
    replay = shlex.split(crashed[0]["replay"])
    assert Path(replay[replay.index("--config") + 1]).is_file()
    again = run_sitl(*replay[1:])
    assert again.returncode == 2, again.stdout + again.stderr
    reason = crashed[0]["error"].strip().splitlines()[-1].split(": ", 1)[1]
    assert f"error: {reason}" in again.stderr, (reason, again.stderr)

    # The report: one file, figures embedded, every failed flight with its command.
    report = (out / "report.html").read_text()
    assert "data:image/png;base64," in report and (out / "paired.png").stat().st_size > 0
    for row in crashed:
        assert row["flight_id"] in report and row["replay"] in report

    # A rerun flies exactly the flight whose row is gone, to the same figures.
    with sqlite3.connect(out / "results.sqlite") as db:
        db.execute("DELETE FROM flights WHERE flight_id = ?", (good["flight_id"],))
    rerun = run_sitl("campaign", str(spec), "--out", str(out), "--workers", "2")
    assert rerun.returncode == 0, rerun.stdout + rerun.stderr
    assert "3 in" in rerun.stdout and "1 to fly on 1 worker" in rerun.stdout
    after = table(out)
    assert after.keys() == rows.keys()
    for flight_id, row in rows.items():
        changed = {k for k in row if k not in TIMING_COLUMNS and row[k] != after[flight_id][k]}
        assert not changed, (flight_id, changed)


def test_the_smoke_spec_gives_the_same_rows_on_the_local_and_the_ray_engine(run_sitl, tmp_path):
    """The shipped smoke spec on two local workers, and its first two flights on Ray (a
    local runtime of 2 CPUs): rows equal but for the timing columns; every flight completed
    and the adaptive one carrying at most half the error of its non-adaptive pair."""
    spec = CAMPAIGNS / "smoke.toml"
    tables = {}
    for engine, limit in (("local", ()), ("ray", ("--limit", "2"))):
        out = tmp_path / engine
        done = run_sitl(
            "campaign", str(spec), "--out", str(out), "--engine", engine, "--workers", "2",
            *limit,
        )  # fmt: skip
        assert done.returncode == 0, done.stdout + done.stderr
        tables[engine] = table(out)
    local, ray = tables["local"], tables["ray"]
    flights = expand(load_spec(spec), spec)
    assert local.keys() == {f.flight_id for f in flights}
    assert ray.keys() == {f.flight_id for f in flights[:2]}
    for flight_id, row in ray.items():
        changed = {k for k in row if k not in TIMING_COLUMNS and row[k] != local[flight_id][k]}
        assert not changed, (flight_id, changed)
    for row in local.values():
        assert row["status"] == "ok" and row["completed"] == 1, row
    pairs: dict[str, dict[str, float]] = {}
    for row in local.values():
        pairs.setdefault(row["pair_id"], {})[row["controller"]] = row["carry_rms_m"]
    assert len(pairs) == 2
    for pair in pairs.values():
        assert pair["passivity"] <= 0.5 * pair["nonadaptive"], pair
    assert {r["worker"] for r in ray.values()} <= {1, 2}


@pytest.mark.parametrize(
    ("engine", "worker"),
    [("local", 2), ("ray", 1)],
)
def test_a_flight_whose_worker_dies_is_flown_once_more_then_recorded_not_retried(
    tmp_path, engine, worker
):
    """A worker stopped under its flight (here by the wall-clock timeout, as a kill -9
    would) loses that flight alone: it is handed to a new worker once (local: a second
    process; Ray: the task cancelled, its worker killed, the flight resubmitted to slot 1),
    and when that one dies too the flight is an error row with its replay command. The
    killed flights' logs do not stay behind in the temporary directory (the local engine's
    is the test's own here; Ray's runtime keeps its sessions in the system's)."""
    spec = write_spec(tmp_path, TINY)
    out = tmp_path / "out"
    temp = tmp_path / "temp"
    temp.mkdir()
    args = ("--engine", engine, "--workers", "1", "--limit", "1", "--flight-timeout", "5")
    command = [sys.executable, "-c", "from sitl.cli import main; main()", "campaign", str(spec)]
    done = subprocess.run(
        [*command, "--out", str(out), *args],
        capture_output=True,
        text=True,
        timeout=600,
        env=dict(os.environ, **({"TMPDIR": str(temp)} if engine == "local" else {})),
    )
    assert done.returncode == 0, done.stdout + done.stderr
    (row,) = table(out).values()
    assert row["status"] == "error" and row["worker"] == worker
    assert row["error"].startswith("not flown: it flew longer than 5 s of wall time, 2 times")
    assert row["replay"].startswith("sitl demo --clock virtual")
    assert list(temp.iterdir()) == []


def test_the_report_lists_the_flights_outside_the_bounds_with_their_replay(tmp_path):
    """From rows alone: the completed flight beyond the mass bound is in the report's bounds
    section with what it broke and its command; the one within them is not."""
    from sitl.campaign.report import write_report

    spec = load_spec(CAMPAIGNS / "envelope.toml")
    base = {
        "status": "ok", "completed": 1, "outcome": "completed", "controller": "passivity",
        "fault": "none", "seed": 0, "pair_id": "p", "version": "1", "com_error_pct": 1.0,
        "placement_error_m": 0.01, "carry_rms_m": 0.01, "carry_max_error_m": 0.02,
        "max_tilt_deg": 3.0, "late_cycles": 0, "cpu_s": 10.0,
    }  # fmt: skip
    rows = [
        base | {"flight_id": "within", "mass_error_pct": 1.0, "replay": None},
        base | {"flight_id": "beyond", "mass_error_pct": -40.0, "replay": "sitl demo X"},
    ]
    report = write_report(rows, [], tmp_path, "t", "", spec).read_text()
    section = report.split("<h2>Flights outside the bounds</h2>")[1]
    assert "1 of 2 flights completed outside the bounds" in section
    assert "beyond" in section and "mass_error_pct -40 (bound 3)" in section
    assert "sitl demo X" in section and "within" not in section


def test_a_refused_payload_is_counted_as_refused_not_as_a_failure(tmp_path):
    """A flight the companion refused at the grasp (``beyond_authority``) is a refusal: in
    its own section of the report with its reason, not among the flights that did not
    complete; a crashed or aborted one still is."""
    from sitl.campaign.report import write_report
    from sitl.campaign.store import failed, refused

    spec = load_spec(CAMPAIGNS / "envelope.toml")
    base = {
        "status": "ok", "completed": 0, "controller": "passivity", "fault": "none",
        "seed": 0, "pair_id": "p", "version": "1", "replay": None, "cpu_s": 10.0,
    }  # fmt: skip
    rows = [
        base | {"flight_id": "heavy", "outcome": "beyond_authority",
                "failure": "MissionFailed: beyond_authority: thrust margin exceeded"},
        base | {"flight_id": "down", "outcome": "aborted", "failure": "ground_contact"},
        base | {"flight_id": "crash", "status": "error", "error": "Traceback\nBoom"},
    ]  # fmt: skip
    assert [refused(r) for r in rows] == [True, False, False]
    assert [failed(r) for r in rows] == [False, True, True]
    report = write_report(rows, [], tmp_path, "t", "", spec).read_text()
    assert "0 completed, 1 refused (beyond authority), 1 flown without completing" in report
    did_not, refusals = report.split("<h2>Flights that did not complete</h2>")[1].split(
        "<h2>Payloads refused (beyond authority)</h2>"
    )
    assert "2 of 3 flights did not complete" in did_not and "heavy" not in did_not
    assert "1 of 3 flights were refused" in refusals and "thrust margin exceeded" in refusals


def test_the_ray_engine_without_ray_or_with_bad_options_is_one_line(
    run_sitl, tmp_path, monkeypatch
):
    from sitl.campaign.ray_engine import RayUnavailableError, run_ray

    monkeypatch.setitem(sys.modules, "ray", None)  # as where the campaign extra is missing
    with pytest.raises(RayUnavailableError, match=r"pip install -e \"\.\[campaign\]\""):
        run_ray([], lambda flight, row: None)
    spec = write_spec(tmp_path, TINY)
    for extra, says in (
        (("--engine", "spark"), "--engine must be local or ray"),
        (("--address", "auto"), "--address names a Ray cluster: it needs --engine ray"),
    ):
        done = run_sitl("campaign", str(spec), "--out", str(tmp_path / "out"), *extra)
        assert done.returncode == 2, done.stdout + done.stderr
        lines = [line for line in done.stderr.splitlines() if line.strip()]
        assert lines == [f"error: {says}"] or (len(lines) == 1 and says in lines[0]), lines


@pytest.mark.slow
@pytest.mark.alone
def test_a_px4_campaign_flies_the_real_px4_and_records_its_flight(run_sitl, px4_build, tmp_path):
    """One flight with the real PX4 SITL build in the loop (at its validated speed), from a
    spec that names it: recorded as px4's, within absolute figures. Alone: at that speed
    the flight takes both cores, and a real-time flight beside it (PX4 SIH's pickup) starved
    into an estimate on its bound and a 15 deg tilt."""
    spec = write_spec(
        tmp_path,
        'autopilots = ["px4"]\n[set]\n"world.payload_position_m" = [0.8, 0.0, 0.05]\n',
    )
    out = tmp_path / "out"
    done = run_sitl("campaign", str(spec), "--out", str(out), "--px4-dir", str(px4_build.root))
    assert done.returncode == 0, done.stdout + done.stderr
    assert "1 to fly on 1 worker" in done.stdout
    (row,) = table(out).values()
    assert row["autopilot"] == "px4" and row["status"] == "ok", row.get("error")
    assert row["completed"] == 1 and json.loads(row["faults"]) == []
    assert abs(row["mass_error_pct"]) < 10.0 and abs(row["com_error_pct"]) < 15.0
    assert row["placement_error_m"] < 0.10 and 0.0 < row["carry_rms_m"] < 0.05
    assert 100.0 < row["control_cycles"] / row["sim_s"] < 130.0  # PX4's ODOMETRY at 125 Hz
    assert "passivity on px4" in (out / "report.html").read_text()


def _rows_when(out: Path, at_least: int, process: subprocess.Popen, timeout_s: float) -> int:
    """Wait until the campaign's table holds ``at_least`` rows; their number."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert process.poll() is None, "the campaign ended early"
        if (out / "results.sqlite").exists():
            try:
                with sqlite3.connect(out / "results.sqlite") as db:
                    have = db.execute("SELECT COUNT(*) FROM flights").fetchone()[0]
            except sqlite3.OperationalError:  # the file made, its table not yet
                have = 0
            if have >= at_least:
                return have
        time.sleep(0.2)
    raise AssertionError(f"fewer than {at_least} rows after {timeout_s:g} s")


@pytest.mark.slow
def test_a_worker_killed_then_ctrl_c_then_a_rerun_leaves_every_flight_once(tmp_path):
    """The smoke spec: its worker killed (SIGKILL) under its flight, the campaign then
    stopped with Ctrl-C (SIGINT) and the same command run again. Every flight is in the
    table exactly once, and the rows written before the stop are unchanged. One worker, so
    that a real-time flight beside this test keeps a core."""
    spec, out = CAMPAIGNS / "smoke.toml", tmp_path / "out"
    command = [sys.executable, "-c", "from sitl.cli import main; main()", "campaign", str(spec)]
    command += ["--out", str(out), "--workers", "1"]
    campaign = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # as from a shell
    )
    try:
        _rows_when(out, 1, campaign, 120.0)
        workers = subprocess.run(
            ["pgrep", "-P", str(campaign.pid), "-f", "spawn_main"], capture_output=True, text=True
        ).stdout.split()
        assert len(workers) == 1, workers
        os.kill(int(workers[0]), signal.SIGKILL)
        _rows_when(out, 2, campaign, 120.0)
        campaign.send_signal(signal.SIGINT)
        stdout, stderr = campaign.communicate(timeout=60)
    finally:
        if campaign.poll() is None:
            campaign.kill()
            campaign.wait()
    assert campaign.returncode == 130, stdout + stderr
    assert "stopped;" in stderr and "Traceback" not in stderr
    before = table(out)
    assert 2 <= len(before) < 4 and all(r["status"] == "ok" for r in before.values())
    again = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stdout + again.stderr
    after = table(out)
    assert after.keys() == {f.flight_id for f in expand(load_spec(spec), spec)}
    for flight_id, row in before.items():
        assert row == after[flight_id]
    assert all(r["status"] == "ok" and r["completed"] == 1 for r in after.values())


def test_the_report_pairs_the_adaptive_controller_with_each_baseline_flown_beside_it(tmp_path):
    """Rows of three pairs (passivity, px4_position) on PX4: the report has the PX4 position
    control section, with the medians, the share of pairs the adaptive carry is lower in and
    at most half in, and its scatter; no non-adaptive section (none flew)."""

    def row(pair, controller, carry_m):
        return {
            "pair_id": pair, "controller": controller, "autopilot": "px4", "status": "ok",
            "completed": 1, "outcome": "completed", "version": "x", "carry_rms_m": carry_m,
            "placement_error_m": 0.01, "carry_max_error_m": 3 * carry_m,
        }  # fmt: skip

    rows = []
    for pair, (adaptive, px4) in enumerate(((0.01, 0.40), (0.012, 0.02), (0.02, 0.015))):
        rows += [row(str(pair), "passivity", adaptive), row(str(pair), "px4_position", px4)]
    report = write_report(rows, [], tmp_path, "baseline").read_text()
    assert "against PX4 position control, paired" in report
    assert "against non-adaptive" not in report
    assert "<td>carry RMS [cm]</td><td>3</td><td>1.20</td><td>2.00</td>" in report
    assert "67 % (at most half in 33 %)" in report
    assert (tmp_path / "paired_px4_position.png").stat().st_size > 0

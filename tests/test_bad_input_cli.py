"""Every bad input of the command lines is one ``error:`` line and exit status 2.

Each case names the input and what is wrong, never prints a traceback, loses nothing and
is found before any work is done. The commands run in this process (typer's runner):
nothing here starts a vehicle or a simulation.
"""

from __future__ import annotations

import json
import math
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner, Result

from companion.cli.main import app as companion_app
from companion.logs.flightlog import FlightLogError, FlightLogWriter
from sitl.cli import app as sitl_app

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
PAPER = CONFIGS / "paper_sim.toml"
PICKUP = CONFIGS / "sitl_pickup.toml"
POINTS = ("--payload-at", "1.5,1.0,0.05", "--place-at", "-1.0,0.5,0.05")


def companion(*args: str | Path) -> Result:
    return CliRunner().invoke(companion_app, [str(a) for a in args])


def sitl(*args: str | Path) -> Result:
    return CliRunner().invoke(sitl_app, [str(a) for a in args])


def one_error(result: Result, *words: str) -> str:
    """The run's one ``error:`` line (status 2, no traceback), which holds ``words``."""
    assert isinstance(result.exception, SystemExit), result.exception
    assert result.exit_code == 2, (result.stdout, result.stderr)
    errors = [line for line in result.stderr.splitlines() if line.strip()]
    errors = [line for line in errors if not line.startswith(("note: ", "warning: "))]
    assert len(errors) == 1 and errors[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.stderr + result.stdout
    for word in words:
        assert word in errors[0], errors[0]
    return errors[0]


def closed_port() -> int:
    """A loopback TCP port nobody listens on (bound, then released)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def changed(tmp_path: Path, source: Path, old: str, new: str) -> Path:
    text = source.read_text()
    assert old in text
    path = tmp_path / f"changed_{source.name}"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.fixture
def no_simulation(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail the test if a simulation starts: the error must come before any work."""
    import sitl.offline.simulation

    def refuse(*args, **kwargs):
        raise AssertionError("the simulation ran before the bad input was found")

    monkeypatch.setattr(sitl.offline.simulation, "simulate", refuse)


# --- configuration files --------------------------------------------------------------


@pytest.mark.parametrize(
    "command",
    [
        ("companion", "check", "{f}"),
        ("companion", "arm", "status", "--bus", "dynamixel:///dev/null", "--config", "{f}"),
        ("companion", "mission", "pickup", "--config", "{f}", *POINTS),
        ("sitl", "check", "{f}"),
        ("sitl", "sim", "--scenario", "{f}", "--out", "{out}"),
        ("sitl", "authority", "--config", "{f}"),
        ("sitl", "run", "--config", "{f}"),
    ],
)
def test_a_config_of_random_bytes(tmp_path, command):
    config = tmp_path / "random.toml"
    config.write_bytes(bytes([0x9F, 0xFF, 0x00, 0xC3]) * 64)
    tool, *args = command
    args = [a.format(f=config, out=tmp_path / "out") for a in args]
    result = (companion if tool == "companion" else sitl)(*args)
    one_error(result, str(config), "not a UTF-8 text file")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("old", "new", "key", "range_"),
    [
        ("mass_kg = 1.0 ", "mass_kg = 1e308 ", "vehicle.mass_kg", "[0.1, 100] kg"),
        ("mass_kg = 1.0 ", "mass_kg = 1e-300 ", "vehicle.mass_kg", "[0.1, 100] kg"),
        ("length_m = 0.2 ", "length_m = 1e9 ", "arm.link1.length_m", "[0.01, 5] m"),
        ("gravity_m_s2 = 9.81", "gravity_m_s2 = 1e30", "environment.gravity_m_s2", "Earth"),
        ("pose_rate_hz = 100.0", "pose_rate_hz = 1e-300", "sensors.pose_rate_hz", "Hz"),
        ("k = [4.5,", "k = [4.5e300,", "controller.k[0]", "[0, 1e+06]"),
    ],
)
def test_numbers_no_vehicle_has_are_refused_with_the_range(tmp_path, old, new, key, range_):
    config = changed(tmp_path, PAPER, old, new)
    for result in (companion("check", config), sitl("check", config)):
        one_error(result, str(config), key, range_)


@pytest.mark.parametrize(
    ("old", "new", "key"),
    [
        ("control_rate_hz = 1000.0", "control_rate_hz = 1e-300", "simulation.control_rate_hz"),
        ("duration_s = 10.0", "duration_s = 1e12", "simulation.duration_s"),
        ("[payload]\nmass_kg = 0.4", "[payload]\nmass_kg = 1e308", "payload.mass_kg"),
    ],
)
def test_simulator_numbers_no_run_has_are_refused(tmp_path, no_simulation, old, new, key):
    config = changed(tmp_path, PAPER, old, new)
    one_error(sitl("check", config), key, "must lie within")
    one_error(sitl("sim", "--scenario", config, "--out", tmp_path / "out"), key)
    assert not (tmp_path / "out").exists()


def nested(tmp_path: Path, depth: int = 600) -> Path:
    """A 1.2 KB TOML of ``depth`` nested arrays: more than the parser's recursion takes."""
    path = tmp_path / "nested.toml"
    path.write_text("x = " + "[" * depth + "]" * depth + "\n")
    return path


def test_a_config_nested_too_deep_is_one_line(tmp_path):
    config = nested(tmp_path)
    for result in (companion("check", config), sitl("check", config)):
        one_error(result, str(config), "nested too deeply")


def test_a_config_over_the_size_limit_is_refused_unread(tmp_path, monkeypatch):
    config = tmp_path / "big.toml"
    config.write_text("# a comment\n" * 100_000)  # valid TOML, 1.1 MiB
    opened = []
    real_open = os.open
    monkeypatch.setattr(os, "open", lambda path, *a: opened.append(path) or real_open(path, *a))
    one_error(companion("check", config), str(config), "too large (1.1 MiB)", "at most 1.0 MiB")
    assert str(config) not in map(str, opened)


def _address_space_limit() -> None:  # in the child: a read without end stops at 2 GiB
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (2 << 30, resource.RLIM_INFINITY))


@pytest.mark.parametrize("scenario", ["/dev/zero", "fifo", "nested.toml"])
def test_a_campaign_spec_whose_scenario_never_ends(tmp_path, scenario):
    """In a subprocess with a timeout and a memory limit: the scenario was read whole (a
    FIFO hung, /dev/zero filled the memory)."""
    os.mkfifo(tmp_path / "fifo")
    nested(tmp_path)
    spec = changed(tmp_path, CONFIGS / "campaigns" / "smoke.toml", "../sitl_pickup.toml", scenario)
    command = ["campaign", str(spec), "--out", str(tmp_path / "out")]
    done = subprocess.run(
        [sys.executable, "-c", "from sitl.entry import main; main()", *command],
        capture_output=True,
        text=True,
        timeout=30,
        preexec_fn=_address_space_limit,
    )
    assert done.returncode == 2, done.stderr[-2000:]
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {spec}: scenario: "), lines
    assert lines[0].endswith(
        {
            "/dev/zero": "cannot read: a character device, not a regular file",
            "fifo": "cannot read: a named pipe (FIFO), not a regular file",
            "nested.toml": "nested too deeply to read",
        }[scenario]
    )
    assert not (tmp_path / "out").exists()


def test_a_campaign_fault_of_unknown_kind_is_one_line(tmp_path):
    spec = changed(
        tmp_path, CONFIGS / "campaigns" / "smoke.toml", 'kind = "none"', 'kind = "meteor"'
    )
    one_error(sitl("campaign", spec, "--out", tmp_path / "out"), "faults[0].kind", "'meteor'")


# --- sitl sim / compare options --------------------------------------------------------


@pytest.mark.parametrize("command", ["sim", "compare"])
@pytest.mark.parametrize(
    ("option", "value", "words"),
    [
        ("--duration", "0.0001", ("--duration", "[0.001, 3600] s", "control step")),
        ("--duration", "nan", ("--duration", "got nan")),
        ("--duration", "inf", ("--duration", "got inf")),
        ("--duration", "-1", ("--duration", "got -1")),
        ("--seed", "-1", ("--seed", "0 or more")),
    ],
)
def test_bad_run_options(tmp_path, no_simulation, command, option, value, words):
    out = tmp_path / "out"
    one_error(sitl(command, "--scenario", PAPER, "--out", out, option, value), *words)
    assert not out.exists()


@pytest.mark.parametrize("command", ["sim", "compare"])
def test_an_output_that_is_a_file_is_refused_before_the_run(tmp_path, no_simulation, command):
    out = tmp_path / "results"
    out.write_text("not a directory")
    one_error(sitl(command, "--scenario", PAPER, "--out", out), str(out), "is a file")
    assert out.read_text() == "not a directory"


@pytest.mark.parametrize("command", ["sim", "compare"])
def test_an_output_that_cannot_be_made_is_refused_before_the_run(tmp_path, no_simulation, command):
    blocker = tmp_path / "file"
    blocker.write_text("")
    out = blocker / "results"  # below a file: no directory can be made there
    one_error(sitl(command, "--scenario", PAPER, "--out", out), str(out), "cannot write")


@pytest.mark.skipif(not Path("/proc/sys/kernel").is_dir(), reason="needs Linux's /proc")
def test_an_output_directory_that_takes_no_files_is_named_as_such(tmp_path, no_simulation):
    result = sitl("sim", "--scenario", PAPER, "--out", "/proc/sys/kernel")
    line = one_error(result, "--out /proc/sys/kernel", "exists but takes no new files")
    assert "No such file" not in line


def test_a_release_before_the_pickup_is_refused(tmp_path, no_simulation):
    out = tmp_path / "out"
    result = sitl(
        "sim", "--scenario", PAPER, "--out", out, "--pickup-at", "0.8", "--release-at", "0.2"
    )
    one_error(result, "--release-at 0.2 s must come after --pickup-at 0.8 s")
    assert not out.exists()


@pytest.mark.parametrize("kind", ["fifo", "symlink-loop", "dev-null"])
def test_an_output_that_is_no_directory_says_what_it_is(tmp_path, kind):
    """In a subprocess with a timeout: a loop of links once made the choice of --out spin
    forever."""
    out = {"fifo": tmp_path / "fifo", "symlink-loop": tmp_path / "a", "dev-null": "/dev/null"}[kind]
    if kind == "fifo":
        os.mkfifo(out)
    elif kind == "symlink-loop":
        os.symlink(tmp_path / "b", tmp_path / "a")
        os.symlink(tmp_path / "a", tmp_path / "b")
    command = ["sim", "--scenario", str(PAPER), "--out", str(out)]
    done = subprocess.run(
        [sys.executable, "-c", "from sitl.entry import main; main()", *command],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert done.returncode == 2, done.stderr
    lines = done.stderr.splitlines()
    what = {
        "fifo": "a named pipe",
        "symlink-loop": "leads nowhere",
        "dev-null": "a character device",
    }
    assert len(lines) == 1 and f"--out {out}: is " in lines[0] and what[kind] in lines[0], lines


def test_sim_results_are_never_overwritten(tmp_path):
    out = tmp_path / "run"
    first = sitl("sim", "--scenario", PAPER, "--out", out, "--duration", "0.01")
    assert first.exit_code == 0, first.stderr
    summary = (out / "summary.json").read_text()
    second = sitl("sim", "--scenario", PAPER, "--out", out, "--duration", "0.02")
    assert second.exit_code == 0, second.stderr
    assert f"writing to {tmp_path / 'run-2'}" in second.stderr
    assert (out / "summary.json").read_text() == summary
    assert (tmp_path / "run-2" / "summary.json").read_text() != summary


def test_demo_output_is_checked_before_the_simulator_starts(tmp_path):
    out = tmp_path / "demo"
    out.write_text("")
    one_error(sitl("demo", "--out", out), str(out), "is a file")
    one_error(sitl("demo", "--out", tmp_path / "d", "--seed", "-1"), "--seed")


# --- companion mission pickup --------------------------------------------------------------


def mission(tmp_path: Path, *extra: str | Path) -> Result:
    args = ["mission", "pickup", "--config", PICKUP, *POINTS, "--out", tmp_path / "m"]
    return companion(*args, "--connect", f"tcpout://127.0.0.1:{closed_port()}", *extra)


def test_mission_refused_connection(tmp_path):
    line = one_error(mission(tmp_path), "--connect tcpout://127.0.0.1:", "refused")
    assert "cannot open" in line
    assert not (tmp_path / "m").exists()


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (("--arm-bus", "nonsense://x"), ("arm bus nonsense://x",)),
        (("--connect", "udpin://127.0.0.1:0"), ("bad connection URL",)),
        (("--connect", "udpin://127.0.0.1:{udp}"), ("heartbeat",)),
    ],
    ids=["arm-bus", "connect", "no-heartbeat"],
)
def test_mission_leaves_no_empty_output_behind(tmp_path, monkeypatch, extra, words):
    """--out (and the parents made with it) is taken away when nothing flew; a directory
    the user had stays."""
    import companion.cli.mission as cli_mission

    monkeypatch.setattr(cli_mission.fly_pickup, "__kwdefaults__", {
        **cli_mission.fly_pickup.__kwdefaults__, "vehicle_timeout_s": 0.2})  # fmt: skip
    out = tmp_path / "new" / "m"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:  # a free UDP port
        sock.bind(("127.0.0.1", 0))
        udp = sock.getsockname()[1]
    extra = tuple(a.format(udp=udp) for a in extra)
    args = ["mission", "pickup", "--config", PICKUP, *POINTS, "--out", out, *extra]
    one_error(companion(*args), *words)
    assert not (tmp_path / "new").exists()
    out.mkdir(parents=True)
    one_error(companion(*args), *words)
    assert out.is_dir()


@pytest.mark.parametrize(
    ("url", "words"),
    [
        ("serial:///dev/no-such-serial-device:921600", ("/dev/no-such-serial-device",)),
        ("udpout://no-such-host.invalid:14550", ("no-such-host.invalid", "cannot open")),
    ],
)
def test_mission_missing_device_or_unknown_host(tmp_path, url, words):
    one_error(mission(tmp_path, "--connect", url), "--connect", *words)


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (None, ("--signing-key", "cannot read")),
        (b"short", ("--signing-key", "32 raw bytes")),
    ],
)
def test_mission_signing_key(tmp_path, content, words):
    key = tmp_path / "signing.key"
    if content is not None:
        key.write_bytes(content)
    one_error(mission(tmp_path, "--signing-key", key), str(key), *words)
    assert not (tmp_path / "m").exists()


@pytest.mark.parametrize("rate", ["0", "nan", "inf", "-5", "1e9"])
def test_mission_control_rate(tmp_path, rate):
    one_error(mission(tmp_path, "--control-rate", rate), "--control-rate", "[2, 1000] Hz")
    assert not (tmp_path / "m").exists()


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--payload-at", "1e9,0,0.05"),
        ("--place-at", "0,-2000,0.05"),
        ("--place-at", "0,0,-500"),
        ("--payload-at", "0,0,500"),
        ("--payload-at", "nan,0,0"),
    ],
)
def test_mission_points_out_of_reach(tmp_path, option, value):
    one_error(mission(tmp_path, option, value), option, value)


@pytest.mark.parametrize("altitude", ["0.2", "1e5", "nan"])
def test_mission_cruise_altitude(tmp_path, altitude):
    one_error(mission(tmp_path, "--cruise-altitude", altitude), "--cruise-altitude", "120 m")


def test_mission_output_that_is_a_file(tmp_path):
    out = tmp_path / "m"
    out.write_text("")
    one_error(mission(tmp_path), "--out", str(out), "is a file")


def test_mission_never_overwrites_an_earlier_flight(tmp_path):
    out = tmp_path / "m"
    out.mkdir()
    (out / "flight.csv").write_text("the first flight\n")
    result = mission(tmp_path)  # refused connection: nothing flies
    one_error(result, "refused")
    assert f"writing to {tmp_path / 'm-2'}" in result.stderr
    assert (out / "flight.csv").read_text() == "the first flight\n"


def test_the_flight_log_writer_never_overwrites(tmp_path):
    path = tmp_path / "flight.csv"
    path.write_text("the first flight\n")
    with pytest.raises(FlightLogError, match="never overwritten"):
        FlightLogWriter(path).open()
    assert path.read_text() == "the first flight\n"


# --- companion plot -------------------------------------------------------------------------


@pytest.fixture
def flight_log(tmp_path) -> Path:
    import numpy as np

    from companion.logs.flightlog import CycleRecord

    path = tmp_path / "flight.csv"
    with FlightLogWriter(path) as log:
        for i in range(50):
            q = np.array([0.1 * i, 0.0, 1.0, 0.0, 0.0, 0.0, -1.5, 0.2])
            log.write(
                CycleRecord(t_vehicle_s=0.004 * i, q=q, q_d=q, px4_mode="OFFBOARD", armed=True)
            )
    return path


@pytest.mark.parametrize("tail", [b"", b"\0" * 4096], ids=["cut", "cut-and-zeros"])
def test_plot_reads_a_cut_log_up_to_its_last_whole_row(tmp_path, flight_log, tail):
    data = flight_log.read_bytes()
    flight_log.write_bytes(data[: data.rfind(b"\n", 0, -1) + 10] + tail)  # last row cut
    result = companion("plot", flight_log, "--out", tmp_path / "fig")
    assert result.exit_code == 0, result.stderr
    assert "49 rows" in result.stdout
    warning = [line for line in result.stderr.splitlines() if line.startswith("warning: ")]
    assert len(warning) == 1 and "line 51 is cut" in warning[0], result.stderr


def test_plot_output_that_is_a_file(tmp_path, flight_log):
    out = tmp_path / "fig"
    out.write_text("")
    one_error(companion("plot", flight_log, "--out", out), str(out), "is a file")


def test_plot_never_overwrites_figures(tmp_path, flight_log):
    out = tmp_path / "fig"
    out.mkdir()
    (out / "tracking.png").write_bytes(b"earlier figure")
    result = companion("plot", flight_log, "--out", out)
    assert result.exit_code == 0, result.stderr
    assert (out / "tracking.png").read_bytes() == b"earlier figure"
    assert (tmp_path / "fig-2" / "tracking.png").stat().st_size > 1000


# --- companion arm --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("ids", "words"),
    [
        ("5-1", ("--ids '5-1'", "empty", "1-5")),
        ("1-300", ("--ids '1-300'", "0-255")),
        ("x", ("--ids 'x'", "1-5,7")),
    ],
)
def test_arm_scan_ids(ids, words):
    one_error(companion("arm", "scan", "--bus", "dynamixel:///dev/null", "--ids", ids), *words)


# --- sitl run --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--onboard-port", "70000"),
        ("--onboard-local-port", "65536"),
        ("--gcs-port", "-1"),
        ("--gcs-local-port", "100000"),
    ],
)
def test_sitl_run_port_out_of_range(option, value):
    one_error(sitl("run", "--config", PICKUP, option, value), option, "0-65535", value)


@pytest.mark.parametrize(
    ("kind", "words"),
    [
        ("missing", ("cannot read", "No such file")),
        ("directory", ("cannot read",)),
        ("short", ("32 raw bytes",)),
    ],
)
def test_sitl_run_signing_key_it_cannot_read(tmp_path, kind, words):
    key = tmp_path / "signing.key"
    if kind == "directory":
        key.mkdir()
    elif kind == "short":
        key.write_bytes(b"0123")
    one_error(sitl("run", "--config", PICKUP, "--signing-key", key), "--signing-key", *words)


def test_sitl_run_never_overwrites_a_truth_log(tmp_path):
    earlier = tmp_path / "truth.jsonl"
    earlier.write_text('{"t_s": 0.0}\n')
    one_error(sitl("run", "--config", PICKUP, "--truth-log", earlier), "--truth-log", "exists")
    assert earlier.read_text() == '{"t_s": 0.0}\n'
    missing = tmp_path / "nowhere" / "truth.jsonl"
    one_error(sitl("run", "--config", PICKUP, "--truth-log", missing), "no directory")


@pytest.mark.parametrize("value", ["-1", "1000", "nan"])
def test_sitl_run_servo_reply_delay_out_of_range(value):
    one_error(
        sitl("run", "--config", PICKUP, "--servo-reply-delay-ms", value),
        "--servo-reply-delay-ms",
        "0 to 999 ms",
    )


@pytest.mark.parametrize(
    ("value", "words"),
    [
        ("99@-3", ("--servo-silent 99@-3", "no servo 99", "1, 2, 3")),
        ("2@nan", ("--servo-silent 2@nan", "[0, 3600] s", "got nan")),
        ("2@-3", ("--servo-silent 2@-3", "[0, 3600] s", "got -3")),
        ("2@1e9", ("--servo-silent 2@1e9", "[0, 3600] s")),
        ("2@hover+3", ("--servo-silent", "ID@PHASE+SECONDS", "takeoff, to_object")),
        ("2@grasp+soon", ("--servo-silent", "ID@PHASE+SECONDS", "got '2@grasp+soon'")),
        ("2@grasp+-1", ("--servo-silent", "offset must be at least 0 s")),
    ],
)
def test_sitl_run_servo_silent_out_of_range(value, words):
    one_error(sitl("run", "--config", PICKUP, "--servo-silent", value), *words)


@pytest.mark.parametrize(
    ("value", "words"),
    [
        ("1@grasp", ("--servo-error", "ID:ERROR@PHASE+SECONDS", "overheating", "got '1@grasp'")),
        ("1:melted@grasp", ("--servo-error", "errors: overload, overheating")),
        ("9:overload@grasp", ("--servo-error 9:overload@grasp", "no servo 9", "1, 2, 3")),
        ("1:overload@-2", ("--servo-error 1:overload@-2", "[0, 3600] s", "got -2")),
        ("1:overload@hover", ("--servo-error", "ID:ERROR@PHASE+SECONDS", "'1:overload@hover'")),
    ],
)
def test_sitl_run_servo_error_out_of_range(value, words):
    one_error(sitl("run", "--config", PICKUP, "--servo-error", value), *words)


@pytest.mark.parametrize(
    ("option", "value", "words"),
    [
        ("--servo-reboot", "1@grasp", ("--servo-reboot", "ID:BOOT@PHASE+SECONDS", "'1@grasp'")),
        ("--servo-reboot", "1:20@grasp", ("--servo-reboot 1:20@grasp", "boot_s", "(0, 10]")),
        ("--servo-reboot", "7:0.1@grasp", ("--servo-reboot 7:0.1@grasp", "no servo 7")),
        ("--link-cut", "long@grasp", ("--link-cut", "DURATION@PHASE+SECONDS", "'long@grasp'")),
        ("--link-cut", "0@grasp", ("--link-cut 0@grasp", "duration must lie in (0, 3600] s")),
        ("--link-cut", "2@hover", ("--link-cut", "DURATION@PHASE+SECONDS", "takeoff, to_object")),
        ("--pilot-takeover", "MANUAL@lift", ("--pilot-takeover", "one of POSCTL", "AUTO_RTL")),
        ("--pilot-takeover", "AUTO_RTL@-1", ("--pilot-takeover AUTO_RTL@-1", "[0, 3600] s")),
        ("--low-battery", "6@lift", ("--low-battery", "needs --autopilot px4")),
        ("--pose-dropout", "3@lift", ("--pose-dropout", "needs --autopilot px4")),
        ("--pose-jump", "0.5@lift", ("--pose-jump", "needs --autopilot px4")),
        ("--link-latency", "3:5@lift", ("--link-latency 3:5@lift", "delay must lie in (0, 2] s")),
    ],
)
def test_sitl_run_link_and_autopilot_faults_out_of_range(option, value, words):
    one_error(sitl("run", "--config", PICKUP, option, value), *words)


@pytest.mark.parametrize("speed", ["-1", "0", "nan", "inf"])
def test_sitl_run_speed_is_blamed_not_the_config(speed):
    line = one_error(sitl("run", "--config", PICKUP, "--speed", speed), "--speed", "positive")
    assert str(PICKUP) not in line


def test_sitl_run_prints_the_ports_it_bound():
    result = sitl(
        "run", "--config", PICKUP, "--onboard-local-port", "0", "--gcs-local-port", "0",
        "--duration", "0.01", "--speed", "10",
    )  # fmt: skip
    assert result.exit_code == 0, result.stderr
    ready = json.loads(
        next(line for line in result.stdout.splitlines() if line.startswith("ready "))[6:]
    )
    for link in ("onboard", "gcs"):
        local = ready[link].split(" -> ")[0]
        assert local.startswith("udp 127.0.0.1:") and int(local.rsplit(":", 1)[1]) > 0, ready


def test_sitl_run_seed_below_zero():
    one_error(sitl("run", "--config", PICKUP, "--seed", "-1"), "--seed", "0 or more", "-1")


# --- help texts -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("tool", "command", "texts"),
    [
        ("companion", ["mission", "pickup"], ["[m, ENU]", "[arm_bus]", "[Hz]", "[m]"]),
        ("companion", ["arm", "move"], ["[deg]", "[arm_bus]"]),
        ("sitl", ["run"], ["[m/s]", "[s, sim time]"]),
        ("sitl", ["sim"], ["[s]"]),
    ],
)
def test_help_shows_units_and_section_names(tool, command, texts):
    result = (companion if tool == "companion" else sitl)(*command, "--help")
    assert result.exit_code == 0
    text = " ".join(result.stdout.split())  # the help wraps lines
    for expected in texts:
        assert expected in text, (expected, result.stdout)


def write_log(path: Path, value: float, every: int) -> Path:
    """A flight log whose q and q_d are ``value`` every ``every``-th row (1: all rows)."""
    import numpy as np

    from companion.logs.flightlog import CycleRecord

    with FlightLogWriter(path) as log:
        for i in range(50):
            q = np.array([0.1 * i, 0.0, 1.0, 0.0, 0.0, 0.0, -1.5, 0.2])
            if i % every == 0:
                q[:] = value
            log.write(CycleRecord(t_vehicle_s=0.004 * i, q=q, q_d=q, px4_mode="OFFBOARD"))
    return path


def test_plot_names_infinite_values_instead_of_matplotlib_warnings(tmp_path):
    log = write_log(tmp_path / "flight.csv", math.inf, every=5)  # written as inf: 1e999 reads so
    result = companion("plot", log, "--out", tmp_path / "fig")
    assert result.exit_code == 0, result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"warning: {log}: infinite values"), lines
    assert "q_x_m (10)" in lines[0]


def test_plot_of_a_log_without_a_number_is_one_error(tmp_path):
    log = write_log(tmp_path / "flight.csv", math.nan, every=1)
    one_error(companion("plot", log, "--out", tmp_path / "fig"), str(log), "holds a number")
    assert not (tmp_path / "fig").exists()

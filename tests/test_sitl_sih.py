"""``sitl sih``: the real PX4 with its SIH vehicle, the arm's servos on a pty.

The command runs in a subprocess as a user runs it (``sitl.vehicle.launch.start_sih``). Tests that
start PX4 need ``PX4_SITL_DIR`` (skipped otherwise, see the ``px4_build`` fixture); each
boots PX4 once (about 5-10 s).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from arm_driver.bus import OperatingMode, open_bus
from companion.config import arm_bus_configs
from sitl.px4_sitl.launcher import Px4Ports
from sitl.px4_sitl.sih import sih_parameters
from sitl.scenario import load_scenario
from sitl.vehicle.launch import start_sih

ROOT = Path(__file__).parent.parent
CONFIG = ROOT / "configs" / "px4_sih_pickup.toml"


def sitl(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``sitl *args`` in a subprocess with ``env`` (default: ours)."""
    return subprocess.run(
        [sys.executable, "-c", "from sitl.cli import main; main()", *args],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )


def assert_usage_error(done: subprocess.CompletedProcess, *words: str) -> None:
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    for word in words:
        assert word in lines[0]


def instance_of(connect_url: str) -> Px4Ports:
    return Px4Ports(int(connect_url.rsplit(":", 1)[1]) - 14540)


def processes_in(workdir: Path) -> list[int]:
    """Processes whose command line names ``workdir`` (PX4 runs ``workdir/bin/px4``)."""
    pids = []
    for entry in Path("/proc").iterdir():
        with contextlib.suppress(OSError):
            if entry.name.isdigit() and str(workdir).encode() in (entry / "cmdline").read_bytes():
                pids.append(int(entry.name))
    return pids


# ---------------------------------------------------------------- user mistakes


def test_without_a_px4_build_it_says_how_to_name_one():
    env = {k: v for k, v in os.environ.items() if k != "PX4_SITL_DIR"}
    assert_usage_error(sitl("sih", "--config", str(CONFIG), env=env), "PX4_SITL_DIR")


def test_a_directory_that_is_no_px4_build_is_refused(tmp_path):
    done = sitl("sih", "--config", str(CONFIG), "--px4-dir", str(tmp_path))
    assert_usage_error(done, str(tmp_path), "bin/px4")


def test_a_scenario_sih_cannot_fly_is_refused(px4_build):
    # sitl_pickup's rotors have a quadratic thrust curve; SIH's motors are linear
    done = sitl("sih", "--config", str(ROOT / "configs" / "sitl_pickup.toml"))
    assert_usage_error(done, "thr_mdl_fac")


@pytest.mark.parametrize(
    ("option", "value", "word"),
    [("--navigation", "rtk", "navigation"), ("--speed-factor", "0", "speed factor")],
)
def test_bad_options_are_refused(px4_build, option, value, word):
    assert_usage_error(sitl("sih", "--config", str(CONFIG), option, value), word)


@pytest.mark.alone
def test_busy_ports_are_refused(px4_build):
    """Alone: it holds every PX4 instance's onboard port, so a PX4 flight starting beside
    it in the parallel phase found no instance free (two CI runs: "no PX4 instance 0-9 has
    all its ports free (0: udp 14540 in use; ...; 9: udp 14549 in use)")."""
    with contextlib.ExitStack() as stack:
        for n in range(10):  # every instance's onboard port taken
            sock = stack.enter_context(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))
            with contextlib.suppress(OSError):  # already taken by someone else: fine too
                sock.bind(("127.0.0.1", Px4Ports(n).onboard_remote))
        done = sitl("sih", "--config", str(CONFIG))
    assert_usage_error(done, "ports")


# ----------------------------------------------------------------------- running


@pytest.mark.usefixtures("no_leaked_bus")
def test_ready_line_mavlink_and_the_arm_bus(px4_build):
    scenario = load_scenario(CONFIG)
    sih = start_sih(CONFIG)
    try:
        assert set(sih.where) >= {"connect", "arm_bus", "px4_log", "onboard", "gcs"}
        assert "watchdog_ms=100" in sih.arm_bus  # the config's Bus Watchdog, flown
        assert sih.px4_log.is_file() and "Ready for takeoff!" in sih.px4_log.read_text()
        ports = instance_of(sih.connect)
        # PX4 on the companion's URL
        link = mavutil.mavlink_connection(sih.connect.replace("udpin://", "udpin:"))
        try:
            heartbeat = link.wait_heartbeat(timeout=10)
            assert heartbeat is not None and heartbeat.autopilot == 12  # MAV_AUTOPILOT_PX4
            assert heartbeat.get_srcSystem() == ports.instance + 1
            link.mav.param_request_read_send(ports.instance + 1, 1, b"SIH_MASS", -1)
            value = link.recv_match(type="PARAM_VALUE", blocking=True, timeout=5)
            assert value.param_value == pytest.approx(sih_parameters(scenario)["SIH_MASS"])
        finally:
            link.close()
        # our driver on the servo bus URL: the arm is where [world] starts it, and moves
        joints, gripper = arm_bus_configs(scenario.arm_bus)

        async def session() -> tuple[dict, dict]:
            # what answers, not how fast: a loaded machine delays the stand's pty thread
            url = sih.arm_bus.replace("timeout_margin_ms=20", "timeout_margin_ms=200")
            async with open_bus(url, joints, gripper=gripper) as bus:
                first = await bus.read_joint_states()
                await bus.set_operating_mode(OperatingMode.POSITION)
                await bus.enable_torque()
                await bus.write_joint_positions({"eta1": -0.4, "eta2": -1.0})
                await asyncio.sleep(1.0)
                return first, await bus.read_joint_states()

        first, held = asyncio.run(session())
        assert set(first) == {"eta1", "eta2"}  # limp until now: swinging from the start pose
        assert held["eta1"].position_rad == pytest.approx(-0.4, abs=0.03)
        assert held["eta2"].position_rad == pytest.approx(-1.0, abs=0.03)
    finally:
        out = sih.stop()
    assert sih.process.returncode == 0, out
    assert "arm stand" in out
    assert not sih.px4_log.exists()  # no --keep-log: PX4's directory removed
    assert processes_in(sih.px4_log.parent) == []


def test_motion_capture_mode_keeps_the_log_and_stops_on_sigterm(px4_build, tmp_path):
    sih = start_sih(CONFIG, "--navigation", "mocap", "--keep-log", str(tmp_path))
    assert "ODOMETRY" in sih.where["mocap"]
    assert sih.px4_log.parent.parent == tmp_path
    link = mavutil.mavlink_connection(sih.connect.replace("udpin://", "udpin:"))
    try:
        assert link.wait_heartbeat(timeout=10) is not None
    finally:
        link.close()
    sih.process.send_signal(signal.SIGTERM)
    out = sih.stop()
    assert sih.process.returncode == 0, out
    assert f"kept in {sih.px4_log.parent}" in out
    log = sih.px4_log.read_text()
    assert "Ready for takeoff!" in log and "mode: Minimal" in log  # the mocap link
    assert "EKF2_GPS_CTRL" in log and "SENS_EN_GPSSIM" in log
    assert processes_in(sih.px4_log.parent) == []


def test_an_interrupt_during_start_up_stops_px4(px4_build, tmp_path):
    args = ["sih", "--config", str(CONFIG), "--keep-log", str(tmp_path)]
    process = subprocess.Popen(
        [sys.executable, "-c", "from sitl.cli import main; main()", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 30.0
    while not list(tmp_path.glob("*/px4.log")) and time.monotonic() < deadline:
        time.sleep(0.1)  # PX4 is booting
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=30)
    assert process.returncode == 1, out + err
    assert "interrupted before PX4 was ready" in err
    assert "ready " not in out
    (workdir,) = tmp_path.iterdir()
    assert processes_in(workdir) == []


def test_px4_dying_ends_sitl_sih_with_an_error(px4_build):
    sih = start_sih(CONFIG)
    (px4,) = processes_in(sih.px4_log.parent / "bin" / "px4")
    os.kill(px4, signal.SIGKILL)
    sih.process.wait(timeout=10)
    out = sih.stop()
    assert sih.process.returncode == 1
    assert "error: PX4 exited" in out
    assert processes_in(sih.px4_log.parent) == []

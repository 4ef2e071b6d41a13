"""The PX4 SITL launcher (``sitl.px4_sitl.launcher``) and the SIH vehicle of a scenario."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from pymavlink import mavutil

from sitl.px4_sitl import launcher
from sitl.px4_sitl.launcher import (
    Px4Build,
    Px4BuildError,
    Px4NotReadyError,
    Px4Ports,
    Px4Sitl,
    free_instance,
    interrupts_held,
    release_instance,
)
from sitl.px4_sitl.sih import SihMismatchError, sih_parameters
from sitl.scenario import load_scenario

ROOT = Path(__file__).parent.parent


def test_sih_parameters_of_the_pickup_vehicle():
    params = sih_parameters(load_scenario(ROOT / "configs" / "px4_sih_pickup.toml"))
    assert params["SIH_MASS"] == pytest.approx(1.22)
    assert params["SIH_T_MAX"] == pytest.approx(6.0)
    assert params["SIH_Q_MAX"] == pytest.approx(0.016 * 6.0)
    assert params["SIH_L_ROLL"] == params["SIH_L_PITCH"] == pytest.approx(0.215)
    # the arm hanging below adds to roll and pitch inertia, not much to yaw
    assert params["SIH_IXX"] > 0.013 and params["SIH_IYY"] > params["SIH_IXX"]
    assert params["SIH_IZZ"] == pytest.approx(0.021, abs=3e-3)


def test_sih_refuses_a_nonlinear_motor_curve():
    with pytest.raises(SihMismatchError, match="thr_mdl_fac"):
        sih_parameters(load_scenario(ROOT / "configs" / "sitl_pickup.toml"))


def test_a_directory_that_is_no_build_is_refused(tmp_path):
    with pytest.raises(Px4BuildError, match="bin/px4"):
        Px4Build.at(tmp_path)
    assert Px4Build.from_env({}) is None


def test_ports_follow_the_instance():
    ports = Px4Ports(3)
    assert (ports.onboard_local, ports.onboard_remote, ports.gcs_local) == (14583, 14543, 18573)
    assert ports.connect_url == "udpin://127.0.0.1:14543"


def test_an_instance_claimed_by_another_process_is_not_chosen():
    """Two processes starting PX4 at once: the instance one chose is not the other's, even
    before PX4 binds its ports."""
    claimer = subprocess.Popen(
        [sys.executable, "-c", CLAIM_AND_WAIT], stdin=subprocess.PIPE, stdout=subprocess.PIPE
    )
    try:
        assert claimer.stdout is not None and claimer.stdin is not None
        theirs = int(claimer.stdout.readline())
        ours = free_instance()
        try:
            assert ours.instance != theirs
        finally:
            release_instance(ours)
        claimer.stdin.close()  # they release on exit
        assert claimer.wait(timeout=10) == 0
    finally:
        claimer.kill()


def test_no_free_instance_says_what_took_each(monkeypatch):
    """Every instance taken: the error names, per instance, the claim or the busy port."""
    busy = Px4Ports(0).onboard_remote
    monkeypatch.setattr(launcher, "_INSTANCES", range(2))
    monkeypatch.setattr(launcher, "_claim", lambda n: n == 0)
    monkeypatch.setattr(launcher, "_udp_free", lambda port: port != busy)
    with pytest.raises(Px4NotReadyError) as error:
        free_instance()
    assert str(error.value).endswith(f"(0: udp {busy} in use; 1: claimed by another process)")


CLAIM_AND_WAIT = """
import sys
from sitl.px4_sitl.launcher import free_instance
print(free_instance().instance, flush=True)
sys.stdin.read()
"""


def test_px4_starts_on_free_ports_answers_and_cleans_up(px4_build):
    scenario = load_scenario(ROOT / "configs" / "px4_sih_pickup.toml")
    # take the first free instance's onboard port: the launcher must pick another one
    taken = free_instance()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", taken.onboard_remote))
        release_instance(taken)
        px4 = Px4Sitl(px4_build, params=sih_parameters(scenario))
        px4.start()
    try:
        assert px4.ports.instance != taken.instance
        link = mavutil.mavlink_connection(f"udpin:127.0.0.1:{px4.ports.onboard_remote}")
        try:
            heartbeat = link.wait_heartbeat(timeout=10)
            assert heartbeat is not None and heartbeat.autopilot == 12  # MAV_AUTOPILOT_PX4
            system = heartbeat.get_srcSystem()  # PX4 instance N is system N + 1
            link.mav.param_request_read_send(system, 1, b"SIH_MASS", -1)
            value = link.recv_match(type="PARAM_VALUE", blocking=True, timeout=5)
            assert value is not None and value.param_value == pytest.approx(1.22)
        finally:
            link.close()
    finally:
        workdir = px4.workdir
        px4.stop()
    assert not px4.alive()
    assert not workdir.exists()


def test_a_start_that_never_gets_ready_stops_px4_and_keeps_its_log(px4_build, tmp_path):
    px4 = Px4Sitl(px4_build, keep_dir=tmp_path, ready_lines=("a line PX4 never prints",))
    with pytest.raises(Px4NotReadyError, match="not ready within"):
        px4.start(timeout_s=3.0)
    assert not px4.alive()
    assert "px4 starting" in px4.log_path.read_text().lower()
    assert px4.log_path.parent.parent == tmp_path


@pytest.fixture
def python_sigint():
    """SIGINT raised as KeyboardInterrupt (Python's default) for the test, then as before."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_an_interrupt_is_held_to_the_end_of_the_block_and_then_raised(python_sigint):
    finished = False
    with pytest.raises(KeyboardInterrupt):
        with interrupts_held():
            os.kill(os.getpid(), signal.SIGINT)
            finished = True
    assert finished
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    assert signal.getsignal(signal.SIGTERM) is not signal.default_int_handler  # untouched


def test_interrupts_are_not_held_outside_the_main_thread(python_sigint):
    seen: list[object] = []

    def run() -> None:
        with interrupts_held():
            seen.append(signal.getsignal(signal.SIGINT))

    worker = threading.Thread(target=run)
    worker.start()
    worker.join()
    assert seen == [signal.default_int_handler]


def test_an_interrupt_while_px4_is_being_spawned_leaves_it_known_and_stopped(
    px4_build, monkeypatch, python_sigint
):
    """Ctrl-C landing inside ``Popen`` (after the fork): PX4 is still stopped by ``stop``."""
    real_popen = subprocess.Popen

    def interrupted_popen(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)
        return real_popen(*args, **kwargs)

    monkeypatch.setattr(launcher.subprocess, "Popen", interrupted_popen)
    px4 = Px4Sitl(px4_build)
    with pytest.raises(KeyboardInterrupt):
        px4.start(timeout_s=10.0)
    monkeypatch.undo()
    process = px4.process
    assert process is not None  # known, so it can be stopped
    px4.stop()
    assert process.poll() is not None

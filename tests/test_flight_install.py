"""The flight install (``pip install .``, no extra) in a fresh venv: what flies, and nothing
of the simulator. The same install flies the non-adaptive pickup: against real PX4 in the
loop of our physics where the PX4 build is present (``test_px4_hil``), against the
imitation elsewhere (``test_mission_e2e``)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

SIMULATOR_ONLY = ("pinocchio", "jsbsim", "mavsdk", "sympy")


def _run(python, *args: str) -> subprocess.CompletedProcess:
    """``python *args`` outside the repository (its packages must not shadow the install)."""
    return subprocess.run(
        [str(python), *args], capture_output=True, text=True, timeout=300, cwd=python.parent
    )


def test_the_flight_install_has_none_of_the_simulator(flight_install):
    probe = (
        "import importlib.util as u, sys\n"
        "print(' '.join(m for m in sys.argv[1:] if u.find_spec(m)))"
    )
    done = _run(flight_install, "-c", probe, *SIMULATOR_ONLY)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == []


def test_the_flight_install_imports_every_companion_module(flight_install):
    walk = (
        "import importlib, pkgutil, companion, arm_driver, bytelink\n"
        "for pkg in (companion, arm_driver, bytelink):\n"
        "    for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.'):\n"
        "        importlib.import_module(m.name)\n"
        "print(companion.__file__)"
    )
    done = _run(flight_install, "-c", walk)
    assert done.returncode == 0, done.stderr[-2000:]
    assert Path(done.stdout.strip()).is_relative_to(flight_install.parent.parent)


def test_the_flight_install_has_the_mission_command(flight_install):
    companion = flight_install.parent / "companion"
    done = subprocess.run(
        [str(companion), "mission", "pickup", "--help"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=companion.parent,
    )
    assert done.returncode == 0, done.stderr
    assert "--connect" in done.stdout and "--arm-bus" in done.stdout


def test_the_simulator_command_says_how_to_install_it(flight_install):
    done = subprocess.run(
        [str(flight_install.parent / "sitl"), "demo"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=flight_install.parent,
    )
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith("error: the simulator needs pinocchio, jsbsim") and "[sim]" in line


FLIGHT_TESTS = (
    "test_arm_bus.py", "test_arm_driver_errors.py", "test_dynamixel_control_table.py",
    "test_dynamixel_instructions.py", "test_dynamixel_protocol.py", "test_dynamixel_stream.py",
    "test_dynamixel_transport.py", "test_dynamixel_units.py", "test_failsafe.py",
    "test_filters.py", "test_flight_control.py", "test_flightlog.py", "test_link_fanout.py",
    "test_link_mavlink.py", "test_link_px4_modes.py", "test_link_telemetry.py",
    "test_link_url.py", "test_loop_period.py", "test_mission.py", "test_navigation.py",
    "test_offboard.py", "test_vehicle_params.py",
)  # fmt: skip
"""The tests of what flies that need nothing of the simulator."""


def test_the_flight_tests_pass_in_the_flight_install(flight_install):
    here = Path(__file__).parent
    for name in FLIGHT_TESTS:
        text = (here / name).read_text()
        assert not re.search(r"^\s*(from|import) (sitl|pinocchio|jsbsim|mavsdk)\b", text, re.M)
    runner = _run(flight_install, "-m", "pip", "install", "--quiet", "pytest", "hypothesis")
    assert runner.returncode == 0, runner.stderr[-2000:]
    # From the repository (the tests read configs/ relative to it), with -P: the working
    # directory is not put on sys.path, so the installed companion is what they import.
    root = here.parent
    where = subprocess.run(
        [str(flight_install), "-P", "-c", "import companion; print(companion.__file__)"],
        capture_output=True, text=True, cwd=root,
    )  # fmt: skip
    assert Path(where.stdout.strip()).is_relative_to(flight_install.parent.parent), where
    done = subprocess.run(
        [str(flight_install), "-P", "-m", "pytest", "-q", "-p", "no:cacheprovider",
         *(str(here / name) for name in FLIGHT_TESTS)],
        capture_output=True, text=True, timeout=900, cwd=root,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-2000:]
    assert " passed" in done.stdout and "error" not in done.stdout.splitlines()[-1]

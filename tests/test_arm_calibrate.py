"""``companion arm calibrate`` against the arm stand: the scenario's two-link arm on a held
base under gravity, its XM430 models on a pty (:mod:`sitl.servo.arm_stand`), the servos'
true torque constant 10 % off the config's (``plant.servo_torque_constant_mismatch``).

The command runs as a user runs it, in a subprocess (``run_cli``, or ``Popen`` where the
test acts while it runs); the stand steps in real time in this process.
"""

from __future__ import annotations

import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from arm_driver.dynamixel import control_table as ct
from companion.config import arm_bus_configs, load_config
from sitl.scenario import Scenario, load_scenario
from sitl.servo import Faults
from sitl.servo.arm_stand import ArmStand

# The stand steps in real time and the calibration waits on it: those tests run alone (the
# user errors need no stand).

CONFIG = Path(__file__).parent.parent / "configs" / "px4_sih_pickup.toml"


def stand_of(mismatch: float = 1.0, scenario: Scenario | None = None) -> ArmStand:
    """The stand, its joints holding the start pose (position mode, torque on)."""
    scenario = scenario if scenario is not None else load_scenario(CONFIG)
    plant = scenario.plant.model_copy(update={"servo_torque_constant_mismatch": mismatch})
    stand = ArmStand(scenario.model_copy(update={"plant": plant}))
    for _, servo in stand.joints:
        assert servo.write(ct.TORQUE_ENABLE.address, b"\x01").error == 0
    return stand


@pytest.fixture
def stand() -> Iterator[ArmStand]:
    with stand_of() as running:
        yield running


def url(stand: ArmStand) -> str:
    # The emulator, the stand and the test share the GIL (5 ms switches): a reply can wait
    # several of them, far beyond a real servo's.
    return f"dynamixel://{stand.device}?timeout_margin_ms=200"


def comments(text: str) -> list[str]:
    return [line.split("#", 1)[1] for line in text.splitlines() if "#" in line]


@pytest.mark.slow
@pytest.mark.alone
@pytest.mark.parametrize("mismatch", [1.1])
def test_calibrate_recovers_the_torque_constant_and_friction_and_writes_them(
    run_cli, tmp_path: Path, mismatch: float
) -> None:
    # GIVEN servos whose torque constant is 10 % off the config's datasheet value (servos
    # weaker than it: the mission's servo check, tests/test_virtual_flights.py)
    config = tmp_path / "arm.toml"
    shutil.copy(CONFIG, config)
    before = load_config(config)
    with stand_of(mismatch) as stand:
        start = stand.joint_state()[0]
        # WHEN the calibration runs and writes its results
        done = run_cli("arm", "calibrate", "--bus", url(stand), "--config", str(config), "--write")
        # THEN the arm is back where it started, holding there as it did
        assert done.returncode == 0, done.stderr
        assert stand.joint_state()[0] == pytest.approx(start, abs=0.03)
        assert all(servo.torque_enabled for _, servo in stand.joints)
        truth = [servo.parameters for _, servo in stand.joints]
        profile = [servo.get(ct.PROFILE_VELOCITY) for _, servo in stand.joints]
    assert profile == [0, 0]  # the factory value again
    assert "wrote" in done.stdout
    # and the config loads with each joint's constant within 3 % and friction within 25 %
    joints, _ = arm_bus_configs(load_config(config).arm_bus)
    for joint, servo in zip(joints, truth, strict=True):
        assert joint.torque_constant_n_m_per_a == pytest.approx(
            servo.torque_constant_n_m_per_a, rel=0.03
        )
        assert joint.viscous_friction_n_m_s_per_rad == pytest.approx(
            servo.viscous_friction_n_m_s_per_rad, rel=0.25
        )
        assert joint.coulomb_friction_n_m == 0.0  # the XM430 model has none
    written = load_config(config).arm_bus
    assert written is not None and all(j.torque_calibrated for j in written.joints)
    # with the rest of the config and every comment as they were
    assert load_config(config).model_dump(exclude={"arm_bus"}) == before.model_dump(
        exclude={"arm_bus"}
    )
    old, new = comments(CONFIG.read_text()), comments(config.read_text())
    dated = re.compile(r" companion arm calibrate, \d{4}-\d{2}-\d{2}$")  # on added keys
    assert [c for c in new if not dated.fullmatch(c)] == old


@pytest.mark.slow
@pytest.mark.alone
def test_too_little_gravity_torque_at_the_poses_is_refused(run_cli, tmp_path: Path) -> None:
    """Limits that keep the arm hanging straight down: no gravity torque to calibrate on."""
    scenario = load_scenario(CONFIG)
    section = scenario.arm_bus
    hanging = [(-1.62, -1.52), (-0.05, 0.05)]
    joints = tuple(
        joint.model_copy(update={"position_min_rad": low, "position_max_rad": high})
        for joint, (low, high) in zip(section.joints, hanging, strict=True)
    )
    text = CONFIG.read_text()
    for old, (low, high) in zip(section.joints, hanging, strict=True):
        text = text.replace(
            f"position_min_rad = {old.position_min_rad!r}", f"position_min_rad = {low}"
        )
        text = text.replace(
            f"position_max_rad = {old.position_max_rad!r}", f"position_max_rad = {high}"
        )
    config = tmp_path / "hanging.toml"
    config.write_text(text)
    assert [j.position_min_rad for j in arm_bus_configs(load_config(config).arm_bus)[0]] == [
        j.position_min_rad for j in joints
    ]
    world = scenario.world.model_copy(update={"start_joints_rad": (-1.57, 0.0)})
    with stand_of(scenario=scenario.model_copy(update={"world": world})) as stand:
        done = run_cli("arm", "calibrate", "--bus", url(stand), "--config", str(config), "--write")
        torque = [servo.torque_enabled for _, servo in stand.joints]
    assert done.returncode == 2
    assert done.stderr.startswith("error: joint 'eta1': too little gravity torque")
    assert "; joint 'eta2': too little gravity torque" in done.stderr
    assert "refused" in done.stdout  # the table's verdict
    assert done.stderr.strip().endswith("nothing written")
    assert len(done.stderr.strip().splitlines()) == 1
    assert config.read_text() == text
    assert torque == [True, True]  # back to holding the start pose, as before


def test_user_errors_are_one_line_and_status_2(run_cli, tmp_path: Path) -> None:
    cases = [
        (["--bus", "dynamixel:///dev/x"], "calibrate needs --config"),
        (["--bus", "dronecan://can0", "--config", str(CONFIG)], "needs a Dynamixel bus"),
        (["--bus", "nosuch:///dev/x", "--config", str(CONFIG)], "needs a Dynamixel bus"),
        (["--bus", "/dev/ttyUSB0", "--config", str(CONFIG)], "has no backend"),
        (["--bus", "dynamixel:///dev/definitely-missing", "--config", str(CONFIG)], "cannot open"),
        (
            ["--bus", "dynamixel:///dev/x", "--config", str(CONFIG.parent / "paper_sim.toml")],
            "no [arm_bus] section",
        ),
        (["--bus", "dynamixel:///dev/x", "--config", str(tmp_path / "none.toml")], "cannot read"),
        (
            ["--bus", "dynamixel:///dev/x", "--config", str(CONFIG), "--torque-limit", "-1"],
            "--torque-limit",
        ),
    ]
    for args, message in cases:
        done = run_cli("arm", "calibrate", *args)
        assert done.returncode == 2, args
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], lines
        assert "Traceback" not in done.stderr


@pytest.mark.slow
@pytest.mark.alone
def test_a_servo_that_does_not_answer_is_a_user_error(run_cli, stand: ArmStand) -> None:
    stand.bus.set_faults(Faults(silent_ids=frozenset({2})))
    done = run_cli("arm", "calibrate", "--bus", url(stand), "--config", str(CONFIG))
    assert done.returncode == 2
    assert done.stderr.startswith("error: servo 2: no complete status packet")
    assert len(done.stderr.strip().splitlines()) == 1


def calibrate_in_background(stand: ArmStand, config: Path) -> subprocess.Popen:
    """The command started, returned once it has the joints in current-based position mode
    with torque on (it is moving the arm)."""
    # SIGINT as in a terminal, even where the suite runs as a background job (the shell
    # then ignores SIGINT for its children, and Python keeps an ignored SIGINT ignored)
    process = subprocess.Popen(
        [sys.executable, "-c", "from companion.cli.main import main; main()", "arm", "calibrate",
         "--bus", url(stand), "--config", str(config)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    based = int(ct.OperatingMode.CURRENT_BASED_POSITION)
    deadline = time.monotonic() + 60.0
    while not all(s.get(ct.OPERATING_MODE) == based and s.torque_enabled for _, s in stand.joints):
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline, "the calibration did not start moving the arm"
        time.sleep(0.01)
    return process


@pytest.mark.slow
@pytest.mark.alone
def test_a_servo_that_stops_answering_midway_leaves_the_arm_without_torque(
    stand: ArmStand,
) -> None:
    process = calibrate_in_background(stand, CONFIG)
    stand.bus.set_faults(Faults(silent_ids=frozenset({2})))
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and re.match(r"error: servo 2: no complete status packet", lines[0])
    # torque off was written to both: servo 2 carried it out without answering, and the
    # message says it was not confirmed
    assert "torque off not confirmed" in lines[0]
    assert not any(servo.torque_enabled for _, servo in stand.joints)


@pytest.mark.slow
@pytest.mark.alone
def test_ctrl_c_stops_the_calibration_with_torque_off(stand: ArmStand) -> None:
    process = calibrate_in_background(stand, CONFIG)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130
    assert stderr.strip() == "error: interrupted: the calibration stopped, torque off sent"
    assert not any(servo.torque_enabled for _, servo in stand.joints)

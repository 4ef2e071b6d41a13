"""``companion arm scan|status|move`` against the emulators.

Dynamixel runs through the real command line in a subprocess (``run_cli``) on the pty
emulator. python-can's virtual bus exists only inside one process, so the DroneCAN cases
invoke the same typer app in-process (typer's CliRunner).
"""

from __future__ import annotations

import math
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from companion.cli.main import app
from sitl.servo import CanActuator, DroneCanActuatorNode, JointRig, PtyServoBus, XM430Servo

CONFIG = Path(__file__).parent.parent / "configs" / "experiment_arm.toml"


@pytest.fixture
def pty_servos() -> Iterator[PtyServoBus]:
    servos = {i: XM430Servo(i) for i in (1, 2, 3)}
    with PtyServoBus(servos, step_servos=False) as sim, JointRig(servos, sim.lock) as rig:
        rig.set_state(1, 0.3)
        yield sim


@pytest.fixture
def can_node() -> Iterator[DroneCanActuatorNode]:
    actuators = {i: CanActuator(i) for i in (1, 2, 3)}
    channel = f"cli-{uuid.uuid4().hex}"
    with DroneCanActuatorNode(actuators, channel=channel, step_actuators=False) as sim:
        with JointRig(actuators, sim.lock):
            yield sim


def url(sim: PtyServoBus) -> str:
    # The emulator and the rig are Python threads of the test process (5 ms switch
    # interval): a reply can wait several switches, far beyond a real servo's.
    return f"dynamixel://{sim.device}?timeout_margin_ms=100"


def test_scan_lists_model_and_firmware(run_cli, pty_servos: PtyServoBus) -> None:
    done = run_cli("arm", "scan", "--bus", url(pty_servos), "--ids", "0-4")
    assert done.returncode == 0, done.stderr
    rows = [line for line in done.stdout.splitlines() if "XM430-W350" in line]
    assert len(rows) == 3
    assert "1020" in rows[0] and "48" in rows[0]


def test_status_with_default_joints_reads_degrees(run_cli, pty_servos: PtyServoBus) -> None:
    done = run_cli("arm", "status", "--bus", url(pty_servos))
    assert done.returncode == 0, done.stderr
    joint1 = next(line for line in done.stdout.splitlines() if "joint1" in line)
    assert f"{math.degrees(0.3):.1f}" in joint1  # 17.19 deg at the shaft


def test_move_with_the_config_reaches_the_angle(run_cli, pty_servos: PtyServoBus) -> None:
    done = run_cli(
        "arm", "move", "--bus", url(pty_servos), "--joint", "eta2", "--deg", "20",
        "--config", str(CONFIG),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    eta2 = next(line for line in done.stdout.splitlines() if "eta2" in line)
    cells = [cell.strip() for cell in eta2.split("│") if cell.strip()]
    assert cells[:2] == ["eta2", "2"]
    assert float(cells[2]) == pytest.approx(20.0, abs=1.0)
    assert pty_servos.servos[2].torque_enabled  # holds the position after exiting


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["status", "--bus", "nosuch:///dev/x"], "unknown bus backend"),
        (["status", "--bus", "dynamixel:///dev/definitely-missing"], "cannot open"),
        (["status", "--bus", "dynamixel:///dev/x?baud=fast"], "baud"),
        (["scan", "--bus", "dynamixel:///dev/x", "--ids", "a-b"], "--ids"),
        (["move", "--bus", "dynamixel:///dev/x", "--joint", "wrist", "--deg", "3"], "joints are"),
        (["status", "--bus", "dynamixel:///dev/x", "--config", "missing.toml"], "cannot read"),
    ],
)
def test_user_errors_are_one_line_and_status_2(run_cli, args: list[str], message: str) -> None:
    done = run_cli("arm", *args)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0]
    assert "Traceback" not in done.stderr


def test_a_servo_that_does_not_answer_is_a_user_error(run_cli, pty_servos: PtyServoBus) -> None:
    pty_servos.servos.pop(2)
    done = run_cli("arm", "status", "--bus", url(pty_servos))
    assert done.returncode == 2
    assert done.stderr.startswith("error: servo 2: no complete status packet")


def test_a_limit_is_a_user_error(run_cli, pty_servos: PtyServoBus) -> None:
    done = run_cli(
        "arm", "move", "--bus", url(pty_servos), "--joint", "1", "--deg", "200",
    )  # fmt: skip
    assert done.returncode == 2
    assert "outside its limits" in done.stderr and "nothing was sent" in done.stderr


def test_dronecan_scan_status_and_move(can_node: DroneCanActuatorNode) -> None:
    runner = CliRunner()
    scanned = runner.invoke(app, ["arm", "scan", "--bus", can_node.url, "--ids", "1-3"])
    assert scanned.exit_code == 0, scanned.output
    assert scanned.output.count("org.sitl.servo.actuator") == 3
    moved = runner.invoke(
        app, ["arm", "move", "--bus", can_node.url, "--joint", "joint1", "--deg", "-15"]
    )
    assert moved.exit_code == 0, moved.output
    assert can_node.actuators[1].goal_position_rad == pytest.approx(math.radians(-15), abs=2e-3)
    status = runner.invoke(app, ["arm", "status", "--bus", can_node.url])
    assert status.exit_code == 0, status.output
    assert "joint2" in status.output


def test_dronecan_missing_actuator_is_a_user_error(can_node: DroneCanActuatorNode) -> None:
    nobody = f"dronecan://nobody-{uuid.uuid4().hex}?interface=virtual&open_timeout_ms=100"
    result = CliRunner().invoke(app, ["arm", "status", "--bus", nobody])
    assert result.exit_code == 2
    assert "error: servo 1: no complete uavcan.equipment.actuator.Status within 100.0 ms" in (
        result.output
    )
    assert "Traceback" not in result.output

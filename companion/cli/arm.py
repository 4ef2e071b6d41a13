"""``companion arm ...``: bench bring-up of the arm's servo bus.

- ``companion arm scan --bus URL [--ids 1-10]``: the servos that answer, with model and
  firmware (Dynamixel: a Ping per id, 0-252 by default; DroneCAN: actuators publishing
  Status within 1.1 s, and their node's GetNodeInfo);
- ``companion arm status --bus URL [--config FILE]``: mode, torque and every joint's
  position [deg], velocity [deg/s] and torque [N m];
- ``companion arm move --bus URL --joint NAME|INDEX --deg D [--config FILE]``: puts the
  joints in position mode if needed (torque off, mode, torque on: the arm is limp for a
  moment), commands one joint to ``D`` degrees and waits up to 5 s for it to get there.
  The servos keep holding the position after the command exits;
- ``companion arm calibrate --bus URL --config FILE [--write] [--torque-limit N_M]``
  (Dynamixel): each joint's torque constant against gravity and its gearbox friction from
  constant-speed sweeps (:mod:`companion.calibration.arm`), a table, a refusal of a poor
  fit, and with ``--write`` the results in ``FILE``'s ``[[arm_bus.joints]]``, comments kept.

Joints come from the ``[arm_bus]`` section of ``--config`` (a scenario TOML), or, without
it, from :data:`DEFAULT_JOINTS`: ``joint1`` and ``joint2`` on ids 1 and 2, direction +1,
zero offset 0, limits +-180 deg, torque limit 1 N m, torque constant 1.78 N m/A (the
XM430-W350 datasheet's stall torque over stall current). User mistakes (bad URL, no such
device, a servo that does not answer, a limit) print one ``error: ...`` line and exit
with status 2.
"""

from __future__ import annotations

import asyncio
import datetime
import math
import time
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Annotated, Any, TypeVar

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from arm_driver.bus import ArmBus, GripperConfig, JointConfig, OperatingMode, open_bus, scan_bus
from arm_driver.errors import ArmDriverError
from arm_driver.url import parse_bus_url
from companion.calibration.arm import JointCalibration, calibration_joints, fit_joints, measure
from companion.calibration.config_edit import with_joint_values
from companion.cli.usage import EXIT_USAGE
from companion.config import (
    ArmBusSection,
    CompanionConfig,
    ConfigError,
    arm_bus_configs,
    load_config,
    read_toml_document,
)
from companion.model import ManipulatorModel

__all__ = ["DEFAULT_JOINTS", "app"]

T = TypeVar("T")

DEFAULT_JOINTS = (
    JointConfig("joint1", 1, 4.1 / 2.3, torque_max_n_m=1.0),
    JointConfig("joint2", 2, 4.1 / 2.3, torque_max_n_m=1.0),
)
"""Joints used without ``--config`` (see the module docstring)."""
_MOVE_TIMEOUT_S = 5.0
_MOVE_TOLERANCE_RAD = math.radians(1.0)

app = typer.Typer(
    name="arm",
    help="Bench bring-up of the arm's servo bus (Dynamixel or DroneCAN).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)

BusOption = Annotated[
    str,
    typer.Option(
        "--bus",
        help="Bus URL, e.g. dynamixel:///dev/ttyUSB0?baud=1000000 or "
        "dronecan://can0?interface=socketcan&node_id=10.",
    ),
]
ConfigOption = Annotated[
    Path | None,
    typer.Option("--config", help="Scenario TOML whose [arm_bus] section gives the joints."),
]


def _fail(message: str) -> typer.Exit:
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(EXIT_USAGE)


def _run(work: Callable[[], Coroutine[Any, Any, T]]) -> T:
    """Run async work; driver errors and bad input become one line and exit status 2."""
    try:
        return asyncio.run(work())
    except (ArmDriverError, ValueError) as error:
        raise _fail(str(error).splitlines()[0]) from None


def _config(config: Path) -> tuple[CompanionConfig, ArmBusSection]:
    try:
        loaded = load_config(config)
    except ConfigError as error:
        raise _fail(str(error).splitlines()[0]) from None
    if loaded.arm_bus is None:
        raise _fail(f"{config}: no [arm_bus] section")
    return loaded, loaded.arm_bus


def _joints(config: Path | None) -> tuple[tuple[JointConfig, ...], GripperConfig | None]:
    if config is None:
        return DEFAULT_JOINTS, None
    return arm_bus_configs(_config(config)[1])


MAX_SERVO_ID = 255
"""Largest id ``--ids`` accepts: DroneCAN actuator ids are 0-255 (Dynamixel's 0-252; the
backend rejects the ids its protocol cannot address)."""


def _parse_ids(text: str | None) -> list[int] | None:
    if text is None:
        return None
    ids: list[int] = []
    for part in text.split(","):
        low_text, dash, high_text = part.partition("-")
        try:
            low, high = int(low_text), int(high_text if dash else low_text)
        except ValueError:
            raise _fail(f"--ids {text!r}: expected ids and ranges like 1-5,7") from None
        if not 0 <= low <= MAX_SERVO_ID or not 0 <= high <= MAX_SERVO_ID:
            raise _fail(f"--ids {text!r}: {part} is not an id or range of ids 0-{MAX_SERVO_ID}")
        if low > high:
            raise _fail(f"--ids {text!r}: the range {part} is empty (lower id first: {high}-{low})")
        ids.extend(i for i in range(low, high + 1) if i not in ids)
    return ids


@app.command()
def scan(
    bus: BusOption,
    ids: Annotated[
        str | None, typer.Option("--ids", help="Ids to look for, e.g. 1-5,7 (default: all).")
    ] = None,
) -> None:
    """List the servos that answer: id, model, firmware."""
    wanted = _parse_ids(ids)
    found = _run(lambda: scan_bus(bus, wanted))
    if not found:
        raise _fail(f"no servo answered on {bus}")
    table = Table(show_header=True)
    for column in ("id", "model", "firmware"):
        table.add_column(column)
    for device in found:
        table.add_row(str(device.servo_id), device.model, device.firmware)
    Console().print(table)


def _state_table(bus: ArmBus, states: dict[str, Any]) -> Table:
    mode = "unknown" if bus.operating_mode is None else bus.operating_mode.value
    torque = {True: "on", False: "off", None: "unknown"}[bus.torque_enabled]
    table = Table(title=f"mode {mode}, torque {torque}", show_header=True)
    for column in ("joint", "id", "position [deg]", "velocity [deg/s]", "torque [N m]"):
        table.add_column(column, justify="right")
    for joint in bus.joints:
        s = states[joint.name]
        table.add_row(
            joint.name,
            str(joint.servo_id),
            f"{math.degrees(s.position_rad):.2f}",
            f"{math.degrees(s.velocity_rad_s):.2f}",
            f"{s.torque_n_m:.3f}",
        )
    return table


@app.command()
def status(bus: BusOption, config: ConfigOption = None) -> None:
    """Read every joint's state once."""
    joints, gripper = _joints(config)

    async def work() -> Table:
        async with open_bus(bus, joints, gripper=gripper) as arm:
            return _state_table(arm, await arm.read_joint_states())

    Console().print(_run(work))


@app.command()
def move(
    bus: BusOption,
    joint: Annotated[str, typer.Option("--joint", help="Joint name, or its 1-based index.")],
    deg: Annotated[float, typer.Option("--deg", help="Goal joint angle [deg].")],
    config: ConfigOption = None,
) -> None:
    """Move one joint to an angle in position mode and wait for it."""
    joints, gripper = _joints(config)
    names = [j.name for j in joints]
    if joint.isdigit() and 1 <= int(joint) <= len(joints):
        joint = names[int(joint) - 1]
    if joint not in names:
        raise _fail(f"--joint {joint!r}: joints are {names} (or 1-{len(names)})")
    goal = math.radians(deg)

    async def work() -> Table:
        async with open_bus(bus, joints, gripper=gripper) as arm:
            if arm.operating_mode is not OperatingMode.POSITION or arm.torque_enabled is not True:
                await arm.disable_torque()
                await arm.set_operating_mode(OperatingMode.POSITION)
                await arm.enable_torque()
            await arm.write_joint_positions({joint: goal})
            deadline = time.monotonic() + _MOVE_TIMEOUT_S
            while True:
                states = await arm.read_joint_states()
                if abs(states[joint].position_rad - goal) <= _MOVE_TOLERANCE_RAD:
                    return _state_table(arm, states)
                if time.monotonic() > deadline:
                    raise ArmDriverError(
                        f"joint {joint!r} is at {math.degrees(states[joint].position_rad):.1f} "
                        f"deg, not {deg:g} deg, after {_MOVE_TIMEOUT_S:g} s"
                    )
                await asyncio.sleep(0.02)

    Console().print(_run(work))


_CALIBRATED_KEYS = (
    "torque_constant_n_m_per_a",
    "viscous_friction_n_m_s_per_rad",
    "coulomb_friction_n_m",
)
EXIT_INTERRUPTED = 130
"""Exit status after Ctrl-C (128 + SIGINT), as a shell reports it."""


@app.command()
def calibrate(
    bus: BusOption,
    config: Annotated[
        Path | None,
        typer.Option(
            "--config",
            help="Scenario TOML with the arm's model and its [arm_bus] joints (required).",
        ),
    ] = None,
    write: Annotated[
        bool,
        typer.Option(
            "--write",
            help="Store the results in --config's [[arm_bus.joints]], comments and layout kept.",
        ),
    ] = False,
    torque_limit: Annotated[
        float,
        typer.Option(
            "--torque-limit",
            help="Largest torque a joint may use meanwhile [N m] (at most the joint's own).",
        ),
    ] = 1.0,
) -> None:
    """Fit each joint's torque constant and gearbox friction against gravity.

    The vehicle stands on the ground or a stand, the arm free to move within its joint
    limits. The joints hold static poses (current at rest against the empty arm's gravity
    torque: the torque constant), then sweep at constant speed both ways (the friction);
    then they go back to where they were. Torque off on any error or Ctrl-C.
    """
    if config is None:
        raise _fail("calibrate needs --config: the arm's model and joint limits come from it")
    if not (math.isfinite(torque_limit) and torque_limit > 0.0):
        raise _fail(f"--torque-limit {torque_limit:g} must be a positive torque [N m]")
    try:
        backend = parse_bus_url(bus).backend
    except ValueError as error:
        raise _fail(str(error).splitlines()[0]) from None
    if backend != "dynamixel":
        raise _fail(
            f"calibrate needs a Dynamixel bus, not {backend!r}: a DroneCAN actuator reports "
            "its own output torque (no torque constant or friction to calibrate)"
        )
    cfg, section = _config(config)
    joints, _ = arm_bus_configs(section)
    if len(joints) != 2:
        raise _fail(f"{config}: the arm has 2 joints, [arm_bus] lists {len(joints)}")
    model = ManipulatorModel.from_config(cfg)
    driven = calibration_joints(joints, torque_limit)
    try:
        readings = _run(lambda: measure(bus, driven, np.random.default_rng(0)))
    except KeyboardInterrupt:
        typer.echo("error: interrupted: the calibration stopped, torque off sent", err=True)
        raise typer.Exit(EXIT_INTERRUPTED) from None
    results = fit_joints(readings, model, cfg.nominal_theta.as_tuple(), joints)
    Console().print(_calibration_table(results))
    refused = [f"joint {r.joint.name!r}: {r.problem}" for r in results if r.problem is not None]
    if refused:
        raise _fail("; ".join(refused) + "; nothing written")
    values: dict[str, dict[str, float | bool]] = {
        r.joint.name: {
            **dict(
                zip(
                    _CALIBRATED_KEYS,
                    (
                        _rounded(r.torque_constant.torque_constant_n_m_per_a),
                        _rounded(r.friction.viscous_friction_n_m_s_per_rad),
                        _rounded(r.friction.coulomb_friction_n_m),
                    ),
                    strict=True,
                )
            ),
            "torque_calibrated": True,
        }
        for r in results
    }
    if not write:
        typer.echo(f"not written: add --write to store these in {config}")
        return
    note = f"companion arm calibrate, {datetime.date.today().isoformat()}"
    try:
        original = read_toml_document(config).text
        text = with_joint_values(original, values, note, str(config))
    except ConfigError as error:
        raise _fail(str(error).splitlines()[0]) from None
    partial = config.with_name(f".{config.name}.calibrate")
    partial.write_text(text, encoding="utf-8")
    partial.replace(config)
    typer.echo(f"wrote {config}: {', '.join(_CALIBRATED_KEYS)} of {', '.join(values)}")


def _rounded(value: float) -> float:
    """Four significant digits: the fits are good to a few tenths of a percent at best."""
    return float(f"{value:.4g}")


def _calibration_table(results: list[JointCalibration]) -> Table:
    """Config -> fitted values per joint, residuals (static / sweep) and the verdict; the
    caption has the largest gravity torque at the poses and the sample counts."""
    table = Table(title="servo calibration (config -> fitted)", show_header=True)
    for column in ("joint", "Kt [N m/A]", "viscous [N m s/rad]", "Coulomb [N m]"):
        table.add_column(column, justify="right")
    table.add_column("rms [N m]", justify="right")
    table.add_column("verdict")
    caption = []
    for r in results:
        kt, friction, joint = r.torque_constant, r.friction, r.joint
        coulomb = f"{friction.coulomb_friction_n_m:.4g}"
        if friction.coulomb_friction_n_m == 0.0 and math.isfinite(friction.coulomb_estimate_n_m):
            coulomb = (
                f"0 (fit {friction.coulomb_estimate_n_m:+.4f} "
                f"+- {friction.coulomb_standard_error:.4f})"
            )
        table.add_row(
            joint.name,
            f"{joint.torque_constant_n_m_per_a:.4g} -> {kt.torque_constant_n_m_per_a:.4g} "
            f"(+- {100 * kt.relative_standard_error:.2f} %)",
            f"{joint.viscous_friction_n_m_s_per_rad:.4g} -> "
            f"{friction.viscous_friction_n_m_s_per_rad:.4g}",
            coulomb,
            f"{kt.residual_rms_n_m:.4f} / {friction.residual_rms_n_m:.4f}",
            "ok" if r.problem is None else "refused",
        )
        caption.append(
            f"{joint.name}: largest gravity torque {kt.max_gravity_torque_n_m:.3f} N m, "
            f"{kt.poses} poses, {friction.samples} sweep samples"
        )
    table.caption = "rms: static poses / sweeps. " + "; ".join(caption)
    return table

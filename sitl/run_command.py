"""``sitl run``'s options, declared once, and the vehicle they describe.

:class:`RunCommand` is the command's options (its fields, with their ``typer.Option``, are
the command line: :func:`companion.cli.options.options_command`) and their checks:
:meth:`RunCommand.vehicle` turns them into the scenario and the vehicle to run, the PX4
imitation (:class:`~sitl.vehicle.runner.SitlVehicle`) or the real PX4 flying our physics
(:class:`~sitl.hil.Px4InTheLoop`). Every mistake is one ``error:`` line and exit status 2,
before anything starts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, NoReturn

import typer

from companion.cli.usage import fail, load_or_exit
from sitl.cli_options import AutopilotOpt, ConfigOpt, Px4DirOpt, SeedOpt, check_seed
from sitl.hil import HilOptions, Px4InTheLoop
from sitl.hil.sensors import GPS_GRADES
from sitl.physics.jsbsim import Wind
from sitl.px4 import ParamError, SigningKeyError, load_signing_key
from sitl.px4_sitl.launcher import Px4Build, Px4BuildError
from sitl.scenario import MAX_DURATION_S, PayloadSlip, Scenario, load_scenario
from sitl.vehicle.link_faults import TAKEOVER_MODES, LinkLatency, LowBattery, PilotTakeover
from sitl.vehicle.mission_phases import FAULT_PHASES, FaultStart, PhaseStart
from sitl.vehicle.options import SERVO_ERRORS, LinkPorts, RunOptions, ServoError
from sitl.vehicle.runner import SitlVehicle, simulated_servo_ids
from sitl.vehicle.servo_bus_faults import ServoReboot

__all__ = ["RunCommand"]


@dataclass(frozen=True)
class RunCommand:
    """The options of ``sitl run`` (units in the help of each)."""

    config: ConfigOpt
    speed: Annotated[
        float, typer.Option(help="Simulated seconds per wall-clock second (e.g. 5 for 5x).")
    ] = 1.0
    seed: SeedOpt = 0
    noise: Annotated[
        bool, typer.Option("--noise/--no-noise", help="The estimator's errors (or exact).")
    ] = True
    navigation: Annotated[
        str,
        typer.Option(
            help="Estimator aiding: mocap (motion capture; set the global origin to hold) "
            "or gps (GPS and baro)."
        ),
    ] = "mocap"
    duration: Annotated[
        float | None, typer.Option(help="Stop after this many simulated seconds.")
    ] = None
    truth_log: Annotated[
        Path | None, typer.Option(help="Write ground truth here (JSON lines).")
    ] = None
    onboard_port: Annotated[
        int, typer.Option(help="Remote UDP port of the onboard (API) link.")
    ] = 14540
    onboard_local_port: Annotated[int, typer.Option(help="Local UDP port of that link.")] = 14580
    gcs_port: Annotated[int, typer.Option(help="Remote UDP port of the GCS link.")] = 14550
    gcs_local_port: Annotated[int, typer.Option(help="Local UDP port of that link.")] = 18570
    signing_key: Annotated[
        Path | None,
        typer.Option(help="MAVLink 2 signing key file (32 bytes); unsigned input is rejected."),
    ] = None
    physics: Annotated[
        str, typer.Option(help="Truth physics: pinocchio (our plant) or jsbsim.")
    ] = "pinocchio"
    wind: Annotated[
        str | None,
        typer.Option(
            help="Steady wind 'E,N,U' [m/s], world ENU, in place of the scenario's plant.wind_m_s."
        ),
    ] = None
    turbulence: Annotated[
        float,
        typer.Option(help="Dryden turbulence, MIL-F-8785C wind speed at 20 ft [m/s] (jsbsim)."),
    ] = 0.0
    servo_silent: Annotated[
        str | None,
        typer.Option(
            help="Fault injection 'ID@T': servo ID stops answering at T [s, sim time]; or "
            "'ID@PHASE+S': S seconds into a mission phase (e.g. 2@takeoff+8, 1@grasp)."
        ),
    ] = None
    servo_error: Annotated[
        str | None,
        typer.Option(
            help="Fault injection 'ID:ERROR@T' or 'ID:ERROR@PHASE+S': servo ID detects a "
            "hardware error as an XM430 does: the alert bit, and torque off for overload, "
            "overheating and electrical_shock (Shutdown's default), not for input_voltage and "
            "motor_encoder (e.g. 1:overheating@to_place+2)."
        ),
    ] = None
    servo_reboot: Annotated[
        str | None,
        typer.Option(
            help="Fault injection 'ID:BOOT@T' or 'ID:BOOT@PHASE+S': servo ID reboots by itself "
            "(a brown-out): its RAM back at the defaults, torque off, no answer for BOOT [s, sim "
            "time], then limp until torque is enabled (e.g. 1:0.1@excite+0.5)."
        ),
    ] = None
    link_cut: Annotated[
        str | None,
        typer.Option(
            help="Fault injection 'DURATION@T' or 'DURATION@PHASE+S': the onboard link silent "
            "both ways for DURATION [s, sim time] (with --autopilot px4: on the companion "
            "relay), e.g. 10@excite+0.5."
        ),
    ] = None
    link_latency: Annotated[
        str | None,
        typer.Option(
            help="Fault injection 'DELAY:DURATION@T' or 'DELAY:DURATION@PHASE+S': every "
            "message of the onboard link held back DELAY [s] for DURATION [s, sim time], both "
            "ways, in order (with --autopilot px4: on the companion relay), e.g. "
            "0.3:5@excite+0.5."
        ),
    ] = None
    pilot_takeover: Annotated[
        str | None,
        typer.Option(
            help="Fault injection 'MODE@T' or 'MODE@PHASE+S': the ground station switches the "
            "autopilot to MODE (AUTO_RTL, AUTO_LOITER, AUTO_LAND; POSCTL and ALTCTL need manual "
            "control), e.g. AUTO_RTL@lift+0.5."
        ),
    ] = None
    low_battery: Annotated[
        str | None,
        typer.Option(
            help="Fault injection 'PERCENT@T' or 'PERCENT@PHASE+S', --autopilot px4: PX4's "
            "simulated battery falls to PERCENT of its charge within a second (6: below PX4's "
            "critical level), e.g. 6@to_place+0.5."
        ),
    ] = None
    pose_dropout: Annotated[
        str | None,
        typer.Option(
            help="Fault injection 'DURATION@T' or 'DURATION@PHASE+S', --autopilot px4 "
            "--navigation mocap: no motion-capture pose reaches PX4 for DURATION [s, sim "
            "time], e.g. 3@to_place+0.5."
        ),
    ] = None
    pose_jump: Annotated[
        str | None,
        typer.Option(
            help="Fault injection 'METRES@T' or 'METRES@PHASE+S', --autopilot px4 --navigation "
            "mocap: from then on every motion-capture pose lies METRES east of the truth (a "
            "re-calibrated frame or a swapped marker: EKF2 resets onto it), e.g. 0.5@lift+0.5."
        ),
    ] = None
    servo_reply_delay_ms: Annotated[
        float,
        typer.Option(
            help="Extra delay before every servo reply [ms], as a USB-serial adapter's latency "
            "timer adds (an FTDI chip's default is 16 ms)."
        ),
    ] = 0.0
    grasp_fails: Annotated[
        bool,
        typer.Option(
            "--grasp-fails", help="Fault injection: the gripper closes on nothing (no grasp)."
        ),
    ] = False
    payload_slip: Annotated[
        float | None,
        typer.Option(
            help="Fault injection: the grasped object slips out this many seconds after "
            "the grasp [s, sim time]."
        ),
    ] = None
    autopilot: AutopilotOpt = "imitation"
    px4_dir: Px4DirOpt = None
    keep_log: Annotated[
        Path | None,
        typer.Option(help="--autopilot px4: keep PX4's working directory (log, ULog) here."),
    ] = None
    gps: Annotated[
        str,
        typer.Option(help="--autopilot px4 --navigation gps: the receiver, standard or rtk."),
    ] = "standard"
    lockstep: Annotated[
        bool,
        typer.Option(
            "--lockstep",
            help="While the client streams setpoints (SET_ATTITUDE_TARGET or "
            "SET_POSITION_TARGET_LOCAL_NED), step past a pose only once its setpoint is in, as "
            "fast as the two go (the imitation; PX4 keeps its own).",
        ),
    ] = False
    companion_lockstep: Annotated[
        bool,
        typer.Option(
            "--companion-lockstep/--no-companion-lockstep",
            help="--autopilot px4: hold PX4's clock after each frame until the companion has "
            "answered the last pose (a SET_ATTITUDE_TARGET or SET_POSITION_TARGET_LOCAL_NED "
            "stamped with its time) and read the joints: its computing takes no vehicle time, "
            "on an idle or a busy machine (off: the onboard link's relay only forwards).",
        ),
    ] = True
    nice: Annotated[
        int,
        typer.Option(
            help="--autopilot px4: lower the simulator's CPU priority (not PX4's) by this "
            "much (0-19), so that a companion on the same machine keeps its real-time "
            "period; the lockstep pair only slows down."
        ),
    ] = 5

    @property
    def flown_by(self) -> str:
        """Who flies: "the PX4 imitation" or "PX4"."""
        return "the PX4 imitation" if self.autopilot == "imitation" else "PX4"

    def vehicle(self) -> tuple[Scenario, SitlVehicle | Px4InTheLoop]:
        """The scenario (with the options' pickup faults) and the vehicle to run; each
        mistake one ``error:`` line, exit status 2."""
        cfg = load_or_exit(self.config, load_scenario)
        build = self._px4_build()
        self._check_run()
        if self.low_battery is not None and build is None:
            fail("--low-battery flies PX4's own battery and failsafe: it needs --autopilot px4")
        for option, value in (
            ("--pose-dropout", self.pose_dropout),
            ("--pose-jump", self.pose_jump),
        ):
            if value is not None and (build is None or self.navigation != "mocap"):
                fail(f"{option} is a motion-capture fault under PX4's EKF2: it needs "
                     "--autopilot px4 --navigation mocap")  # fmt: skip
        silent = None
        if self.servo_silent is not None:
            silent = _servo_fault(self.servo_silent, simulated_servo_ids(cfg))
        error = None
        if self.servo_error is not None:
            error = _servo_error(self.servo_error, simulated_servo_ids(cfg))
        reboot = None
        if self.servo_reboot is not None:
            reboot = _servo_reboot(self.servo_reboot, simulated_servo_ids(cfg))
        if not (
            math.isfinite(self.servo_reply_delay_ms) and 0.0 <= self.servo_reply_delay_ms < 1000.0
        ):
            fail(f"--servo-reply-delay-ms must be 0 to 999 ms, got {self.servo_reply_delay_ms:g}")
        cfg = _pickup_faults(cfg, self.config, self.grasp_fails, self.payload_slip)
        air = self._air(cfg)
        try:
            options = RunOptions(
                speed=self.speed,
                seed=self.seed,
                noise=self.noise,
                navigation=self.navigation,
                ports=LinkPorts(
                    onboard_local=self.onboard_local_port,
                    onboard_remote=self.onboard_port,
                    gcs_local=self.gcs_local_port,
                    gcs_remote=self.gcs_port,
                ),
                signing_key=self.signing_key,
                truth_log=self.truth_log,
                servo_silent=silent,
                servo_error=error,
                servo_reboot=reboot,
                link_cut=None if self.link_cut is None else _stretch(self.link_cut, "--link-cut"),
                pilot_takeover=None
                if self.pilot_takeover is None
                else _pilot_takeover(self.pilot_takeover),
                low_battery=None if self.low_battery is None else _low_battery(self.low_battery),
                link_latency=None
                if self.link_latency is None
                else _link_latency(self.link_latency),
                pose_dropout=None
                if self.pose_dropout is None
                else _stretch(self.pose_dropout, "--pose-dropout"),
                pose_jump=None if self.pose_jump is None else _pose_jump(self.pose_jump),
                servo_reply_delay_s=self.servo_reply_delay_ms * 1e-3,
                physics=self.physics,
                wind=air,
                lockstep=self.lockstep,
            )
            if build is None:
                return cfg, SitlVehicle(cfg, options)
            hil = HilOptions(
                build,
                keep_dir=self.keep_log,
                gps=self.gps,
                companion_lockstep=self.companion_lockstep,
                nice=self.nice,
            )
            return cfg, Px4InTheLoop(cfg, options, hil)
        except (ValueError, ParamError, SigningKeyError) as exc:
            fail(f"{self.config}: {exc}")

    def _px4_build(self) -> Px4Build | None:
        """The PX4 build that flies (``--autopilot px4``), else None."""
        if self.autopilot not in ("imitation", "px4"):
            fail(f"--autopilot must be imitation or px4, got {self.autopilot!r}")
        px4 = self.autopilot == "px4"
        if px4 and self.px4_dir is None:
            fail("--autopilot px4 needs a PX4 SITL build: pass --px4-dir DIR or set PX4_SITL_DIR")
        if px4 and self.lockstep:
            fail("--lockstep is the imitation's: PX4 in the loop runs in its own lockstep")
        if px4 and self.signing_key is not None:
            fail("--signing-key is the imitation's: configure PX4's own signing (MAV_SIGN_CFG)")
        if self.gps not in GPS_GRADES:
            fail(f"--gps must be one of {', '.join(GPS_GRADES)}, got {self.gps!r}")
        if not px4 or self.px4_dir is None:
            return None
        try:
            return Px4Build.at(self.px4_dir)
        except Px4BuildError as exc:
            fail(str(exc))

    def _check_run(self) -> None:
        """The run's pace, length, seed, truth log, ports and signing key."""
        if not (math.isfinite(self.speed) and self.speed > 0.0):
            fail(f"--speed must be a positive factor (simulated s per wall s), got {self.speed:g}")
        if self.duration is not None and not self.duration > 0.0:
            fail(f"--duration must be positive, got {self.duration:g}")
        check_seed(self.seed)
        if self.truth_log is not None:
            if self.truth_log.exists():
                fail(
                    f"--truth-log {self.truth_log}: exists; an earlier run's truth is never "
                    "overwritten: name a new file"
                )
            if not self.truth_log.parent.is_dir():
                fail(f"--truth-log {self.truth_log}: no directory {self.truth_log.parent}")
        ports = (
            ("--onboard-port", self.onboard_port),
            ("--onboard-local-port", self.onboard_local_port),
            ("--gcs-port", self.gcs_port),
            ("--gcs-local-port", self.gcs_local_port),
        )
        for option, port in ports:
            if not 0 <= port <= 65535:
                fail(f"{option} must be a UDP port number 0-65535, got {port}")
        if self.signing_key is not None:
            try:
                load_signing_key(self.signing_key)
            except SigningKeyError as exc:
                fail(f"--signing-key {exc}")

    def _air(self, cfg: Scenario) -> Wind | None:
        """The physics and navigation named right, and the wind of the options."""
        if self.physics not in ("pinocchio", "jsbsim"):
            fail(f"--physics must be pinocchio or jsbsim, got {self.physics!r}")
        if self.navigation not in ("mocap", "gps"):
            fail(f"--navigation must be mocap or gps, got {self.navigation!r}")
        try:
            air = Wind.from_text(self.wind, self.turbulence, self.seed, cfg.plant.wind_m_s)
        except ValueError as exc:
            fail(str(exc))
        if self.turbulence != 0.0 and self.physics != "jsbsim":
            fail("--turbulence needs --physics jsbsim")
        return air


def _pickup_faults(
    cfg: Scenario, config: Path, grasp_fails: bool, slip_after_s: float | None
) -> Scenario:
    """The scenario with the pickup faults of the options (``--grasp-fails``,
    ``--payload-slip``) in its ``[world]``; one ``error:`` line for a bad value."""
    if not grasp_fails and slip_after_s is None:
        return cfg
    if cfg.world is None or cfg.world.payload_position_m is None:
        fail(f"--grasp-fails and --payload-slip need an object: {config} has no [world] "
             "payload_position_m")  # fmt: skip
    update: dict[str, object] = {}
    if grasp_fails:
        update["grasp_fails"] = True
    if slip_after_s is not None:
        if not (math.isfinite(slip_after_s) and 0.0 <= slip_after_s <= MAX_DURATION_S):
            fail(
                f"--payload-slip must be 0-{MAX_DURATION_S:g} s after the grasp, "
                f"got {slip_after_s:g}"
            )
        update["payload_slip"] = PayloadSlip(after_grasp_s=slip_after_s)
    return cfg.model_copy(update={"world": cfg.world.model_copy(update=update)})


def _servo_fault(
    text: str, servo_ids: tuple[int, ...], option: str = "--servo-silent", shown: str = ""
) -> tuple[int, FaultStart]:
    """``ID@SECONDS`` or ``ID@PHASE[+SECONDS]`` (``option``'s value, ``shown`` as the user
    gave it) as (servo id, start): a servo of the simulated bus (``servo_ids``) and the
    start as :func:`_fault_start` reads it."""
    shown = shown or text
    servo, _, at = text.partition("@")
    try:
        servo_id = int(servo)
    except ValueError:
        _bad_fault(option, shown)
    if servo_id not in servo_ids:
        ids = ", ".join(str(i) for i in servo_ids)
        fail(f"{option} {shown}: no servo {servo_id} on the simulated bus (its ids: {ids})")
    return servo_id, _fault_start(at, option, shown)


def _fault_start(at: str, option: str, shown: str) -> FaultStart:
    """``SECONDS`` or ``PHASE[+SECONDS]`` (after the ``@`` of ``option``'s value ``shown``)
    as a start: a simulated time within the longest run [s], or a moment into a mission
    phase (:data:`~sitl.vehicle.mission_phases.FAULT_PHASES`)."""
    phase, plus, offset = at.partition("+")
    try:
        start: FaultStart
        if phase in FAULT_PHASES:
            start = PhaseStart(phase, float(offset) if plus else 0.0)
        else:
            start = float(at)
    except ValueError as error:
        _bad_fault(option, shown, f": {error}" if phase in FAULT_PHASES else "")
    if isinstance(start, float) and not (math.isfinite(start) and 0.0 <= start <= MAX_DURATION_S):
        fail(
            f"{option} {shown}: the time must lie in [0, {MAX_DURATION_S:g}] s of "
            f"simulated time, got {start:g}"
        )
    return start


def _number(text: str, option: str, shown: str) -> float:
    """The number ``text`` of ``option``'s value ``shown``; one ``error:`` line otherwise."""
    try:
        return float(text)
    except ValueError:
        _bad_fault(option, shown)


def _bad_fault(option: str, shown: str, why: str = "") -> NoReturn:
    """One ``error:`` line: ``option``'s forms and an example, and what was given."""
    fail(
        f"{option} needs {_FORMS[option]} (phases: {', '.join(FAULT_PHASES)}), "
        f"e.g. {_EXAMPLES[option]}, got {shown!r}{why}"
    )


def _stretch(text: str, option: str, shown: str = "") -> tuple[FaultStart, float]:
    """``option``'s ``SECONDS@START`` (``shown`` as the user gave it) as (start,
    duration [s])."""
    shown = shown or text
    duration, _, at = text.partition("@")
    duration_s = _number(duration, option, shown)
    if not (math.isfinite(duration_s) and 0.0 < duration_s <= MAX_DURATION_S):
        fail(f"{option} {shown}: the duration must lie in (0, {MAX_DURATION_S:g}] s")
    return _fault_start(at, option, shown), duration_s


def _pose_jump(text: str) -> tuple[FaultStart, float]:
    """``--pose-jump METRES@START`` as (start, distance east [m])."""
    metres, _, at = text.partition("@")
    distance_m = _number(metres, "--pose-jump", text)
    if not (math.isfinite(distance_m) and 0.0 < abs(distance_m) <= 10.0):
        fail(f"--pose-jump {text}: the jump must be non-zero and at most 10 m")
    return _fault_start(at, "--pose-jump", text), distance_m


def _link_latency(text: str) -> LinkLatency:
    """``--link-latency DELAY:DURATION@START`` as a :class:`LinkLatency`."""
    delay, colon, stretch = text.partition(":")
    delay_s = _number(delay, "--link-latency", text)
    if not colon or not (math.isfinite(delay_s) and 0.0 < delay_s <= 2.0):
        fail(f"--link-latency {text}: the delay must lie in (0, 2] s, before a ':'")
    start, duration_s = _stretch(stretch, "--link-latency", text)
    return LinkLatency(start, duration_s, delay_s)


def _pilot_takeover(text: str) -> PilotTakeover:
    """``--pilot-takeover MODE@START`` as a :class:`PilotTakeover`."""
    mode, _, at = text.partition("@")
    if mode not in TAKEOVER_MODES:
        fail(f"--pilot-takeover {text}: the mode must be one of {', '.join(TAKEOVER_MODES)}")
    return PilotTakeover(_fault_start(at, "--pilot-takeover", text), mode)


def _low_battery(text: str) -> LowBattery:
    """``--low-battery PERCENT@START`` as a :class:`LowBattery`."""
    percent, _, at = text.partition("@")
    remaining = _number(percent, "--low-battery", text)
    if not 0.0 <= remaining < 100.0:
        fail(f"--low-battery {text}: the remaining charge must be 0 to 100 %")
    return LowBattery(_fault_start(at, "--low-battery", text), remaining)


_FORMS = {
    "--servo-silent": "ID@SECONDS or ID@PHASE+SECONDS",
    "--servo-error": "ID:ERROR@SECONDS or ID:ERROR@PHASE+SECONDS",
    "--servo-reboot": "ID:BOOT@SECONDS or ID:BOOT@PHASE+SECONDS",
    "--link-cut": "DURATION@SECONDS or DURATION@PHASE+SECONDS",
    "--pilot-takeover": "MODE@SECONDS or MODE@PHASE+SECONDS",
    "--low-battery": "PERCENT@SECONDS or PERCENT@PHASE+SECONDS",
    "--pose-dropout": "DURATION@SECONDS or DURATION@PHASE+SECONDS",
    "--pose-jump": "METRES@SECONDS or METRES@PHASE+SECONDS",
    "--link-latency": "DELAY:DURATION@SECONDS or DELAY:DURATION@PHASE+SECONDS",
}
_EXAMPLES = {
    "--servo-silent": "2@30 or 2@takeoff+8",
    "--servo-error": "1:overheating@grasp+0.5",
    "--servo-reboot": "1:0.1@excite+0.5",
    "--link-cut": "10@excite+0.5",
    "--pilot-takeover": "AUTO_RTL@lift+0.5",
    "--low-battery": "6@to_place+0.5",
    "--pose-dropout": "3@to_place+0.5",
    "--pose-jump": "0.5@lift+0.5",
    "--link-latency": "0.3:5@excite+0.5",
}


def _servo_reboot(text: str, servo_ids: tuple[int, ...]) -> ServoReboot:
    """``--servo-reboot ID:BOOT@START`` as a :class:`ServoReboot` (the boot time in (0, 10]
    s, the start as ``--servo-silent``'s)."""
    servo, _, rest = text.partition(":")
    boot, at, start = rest.partition("@")
    try:
        boot_s = float(boot)
    except ValueError:
        _bad_fault("--servo-reboot", text)
    if not at:
        _bad_fault("--servo-reboot", text)
    servo_id, when = _servo_fault(f"{servo}@{start}", servo_ids, "--servo-reboot", text)
    try:
        return ServoReboot(servo_id, when, boot_s)
    except ValueError as exc:
        fail(f"--servo-reboot {text}: {exc}")


def _servo_error(text: str, servo_ids: tuple[int, ...]) -> ServoError:
    """``--servo-error ID:ERROR@START`` as a :class:`ServoError` (an error of
    :data:`SERVO_ERRORS`, the start as ``--servo-silent``'s)."""
    servo, _, rest = text.partition(":")
    error, at, start = rest.partition("@")
    if error not in SERVO_ERRORS or not at:
        fail(
            f"--servo-error needs {_FORMS['--servo-error']} (errors: "
            f"{', '.join(SERVO_ERRORS)}), e.g. {_EXAMPLES['--servo-error']}, got {text!r}"
        )
    servo_id, when = _servo_fault(f"{servo}@{start}", servo_ids, "--servo-error", text)
    return ServoError(servo_id, error, when)

"""The fault sample with the real PX4 in the loop: PX4's own failsafes judged on our physics.

Four faults where PX4 is the one reacting, each at three phases of the pickup (12 flights):

- ``pilot_takeover``: the ground station switches PX4 to Return (``sitl run
  --pilot-takeover AUTO_RTL@PHASE+0.5``);
- ``offboard_loss``: the companion's link silent both ways for 10 s, far past
  ``COM_OF_LOSS_T`` (``--link-cut 10@PHASE+0.5``, on the relay of the onboard link);
- ``low_battery``: PX4's simulated battery falls to 6 %, below its critical level
  (``--low-battery 6@PHASE+0.5``; COM_LOW_BAT_ACT 3);
- ``companion_kill``: ``companion mission pickup`` killed with SIGKILL 0.5 s into the phase
  (the phase read from ``sitl run``'s ``phase NAME at T s`` line; the 0.5 s waited in wall
  time at PX4's validated speed).

``--only`` flies three more: ``pose_dropout``, no motion-capture pose reaches PX4's EKF2
for 10 s (``--pose-dropout 10@PHASE+0.5``); ``link_latency``, every message of the onboard
link held back 0.3 s for 5 s (``--link-latency 0.3:5@PHASE+0.5``); ``companion_starved``,
the mission's process left :data:`STARVED_SHARE` of a CPU for :data:`STARVED_S` of wall
time from 0.5 s into the phase (stopped and continued in turn, as a CPU taken by other
work starves it), at speed 1 without the companion lockstep (which would hold PX4's clock
for it: the starvation would cost no vehicle time); the relay still reads the phases.

Each flight: ``sitl run --autopilot px4`` (PX4 SITL flying the hexacopter with its arm, at
:data:`~sitl.hil.vehicle.VALIDATED_SPEED`) and the mission as its own process, as a user
runs them. When the mission's process ends (or is killed) the vehicle flies on under PX4
until it is disarmed on the ground, or :data:`AFTER_S` of wall time. The flight is judged
by docs/faults.md's numbers (:func:`sitl.campaign.safety.judge`) on the truth log, the
summary (none after a kill) and the flight log, which must reach the kill (its last
block) or the moment PX4 last left OFFBOARD (from then on PX4 flies); PX4's mode sequence
is read from its ULog (``vehicle_status``: nav_state, failsafe, arming). With ``--write``
the table goes to ``docs/px4_fault_sample.md``.

    PX4_SITL_DIR=../shared/px4-sitl python benchmarks/px4_fault_sample.py [--write]
        [--only KIND] [--phases P1,P2,P3] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import queue
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from pyulog import ULog

from companion.logs.columns import ColumnsError, T, read_columns
from companion.logs.flightlog import read_flight_log
from sitl.campaign.safety import handover_s, judge
from sitl.hil.vehicle import VALIDATED_SPEED
from sitl.px4_sitl.launcher import Px4Build
from sitl.vehicle.launch import start_sitl

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "configs" / "sitl_pickup.toml"
PAYLOAD_AT = "1.5,1,0.05"
PLACE_AT = (-1.0, 0.5, 0.05)
PHASES = ("descend", "excite", "to_place")
"""Before the grasp, the arm swinging with the object, carrying it."""
OFFSET_S = 0.5
FAULTS: dict[str, tuple[str, str] | None] = {
    "pilot_takeover": ("--pilot-takeover", "AUTO_RTL@{phase}+{offset}"),
    "offboard_loss": ("--link-cut", "10@{phase}+{offset}"),
    "low_battery": ("--low-battery", "6@{phase}+{offset}"),
    "companion_kill": None,
    "pose_dropout": ("--pose-dropout", "10@{phase}+{offset}"),
    "companion_starved": None,
    "link_latency": ("--link-latency", "0.3:5@{phase}+{offset}"),
}
SAMPLE = ("pilot_takeover", "offboard_loss", "low_battery", "companion_kill")
"""The faults the sample flies; the others with ``--only``."""
STARVED_S = 5.0
"""How long the starved companion runs at :data:`STARVED_SHARE` of a CPU [s, wall]."""
STARVED_SHARE = 0.2
"""The CPU share left to it: stopped (SIGSTOP) 40 ms, run (SIGCONT) 10 ms, in turn."""
AFTER_S = 90.0
"""Longest wall time the vehicle flies on under PX4 after the mission's process ended [s]."""
MISSION_TIMEOUT_S = 600.0
NAV_STATES = {
    0: "MANUAL", 1: "ALTCTL", 2: "POSCTL", 3: "AUTO_MISSION", 4: "AUTO_LOITER",
    5: "AUTO_RTL", 6: "POSITION_SLOW", 10: "ACRO", 12: "DESCEND", 13: "TERMINATION",
    14: "OFFBOARD", 15: "STABILIZED", 17: "AUTO_TAKEOFF", 18: "AUTO_LAND",
    20: "AUTO_PRECLAND",
}  # fmt: skip
"""PX4's ``vehicle_status.nav_state`` values (``msg/VehicleStatus.msg``) by display name."""


@dataclass
class Flown:
    kind: str
    phase: str
    safe: bool
    broken: tuple[str, ...]
    end: str
    touchdown_m_s: float | None
    max_tilt_deg: float
    payload: str
    outcome: str
    px4_modes: str
    log_until_s: float | None
    """Vehicle time the companion's log must reach [s]: the kill, or PX4 leaving OFFBOARD."""
    wall_s: float
    work: Path


def px4_modes(px4_dir: Path) -> tuple[str, float | None]:
    """PX4's mode sequence from the ULog under ``px4_dir``: ``MODE@T`` per change of
    nav_state (``!`` marks a failsafe, ``disarmed@T`` the disarm), T in PX4's time [s] (the
    truth's, in lockstep); and the time of the disarm [s] (None: never disarmed)."""
    logs = sorted(px4_dir.rglob("*.ulg"))
    if not logs:
        return "no ULog", None
    status = ULog(str(logs[-1]), ["vehicle_status"]).get_dataset("vehicle_status").data
    sequence: list[str] = []
    last: tuple[int, int, int] | None = None
    armed_seen = False
    disarmed_s = None
    for t_us, nav, failsafe, arming in zip(
        status["timestamp"], status["nav_state"], status["failsafe"], status["arming_state"],
        strict=True,
    ):  # fmt: skip
        t_s = t_us * 1e-6
        key = (int(nav), int(failsafe), int(arming))
        if key == last:
            continue
        if last is None or key[:2] != last[:2]:
            name = NAV_STATES.get(key[0], str(key[0]))
            sequence.append(f"{name}{'!' if key[1] else ''}@{t_s:.1f}")
        if arming == 2:
            armed_seen = True
        elif armed_seen and (last is not None and last[2] == 2):
            sequence.append(f"disarmed@{t_s:.1f}")
            disarmed_s = t_s
        last = key
    return " ".join(sequence), disarmed_s


def _read_truth(path: Path) -> list[dict]:
    if not path.exists():
        return []
    lines = path.read_text(encoding="utf-8").splitlines()
    return [json.loads(line) for line in lines if line.strip().endswith("}")]


def _log_end_s(out: Path) -> float | None:
    """Vehicle time of the flight log's last row [s]: ``flight.csv``, or after a kill the
    binary columns it left (``flight.columns``); None when neither reads back."""
    try:
        if (out / "flight.columns").exists():
            rows, _, _ = read_columns(out / "flight.columns")
            column = rows[:, T]
        else:
            column = read_flight_log(out / "flight.csv").columns["t_vehicle_s"]
    except (OSError, ValueError, KeyError, ColumnsError):
        return None
    return float(column[-1]) if len(column) else None


def _await_phase(output: queue.Queue, phase: str, deadline: float) -> float | None:
    """The simulated time [s] of ``sitl run``'s ``phase NAME at T s`` line for ``phase``."""
    prefix = f"phase {phase} at "
    while time.monotonic() < deadline:
        try:
            line = output.get(timeout=0.5)
        except queue.Empty:
            continue
        if line is None:
            return None
        if line.startswith(prefix):
            return float(line[len(prefix) :].split()[0])
    return None


def _starve(process: subprocess.Popen) -> None:
    """Leave ``process`` :data:`STARVED_SHARE` of a CPU for :data:`STARVED_S` [s, wall]."""
    run_s = 0.05 * STARVED_SHARE
    end = time.monotonic() + STARVED_S
    while time.monotonic() < end and process.poll() is None:
        process.send_signal(signal.SIGSTOP)
        time.sleep(0.05 - run_s)
        process.send_signal(signal.SIGCONT)
        time.sleep(run_s)


def fly(build: Px4Build, kind: str, phase: str, work: Path, seed: int = 1) -> Flown:
    """One flight of the sample (module docstring) in ``work``."""
    wall0 = time.monotonic()
    fault = FAULTS[kind]
    extra = [] if fault is None else [fault[0], fault[1].format(phase=phase, offset=OFFSET_S)]
    speed = VALIDATED_SPEED
    if kind == "companion_starved":  # in the lockstep PX4's clock would wait for it
        extra, speed = ["--no-companion-lockstep"], 1.0
    truth_log = work / "truth.jsonl"
    sitl = start_sitl(
        CONFIG, "--seed", str(seed), "--navigation", "mocap", *extra,
        speed=speed, truth_log=truth_log, px4_dir=build.root, px4_log=work / "px4",
    )  # fmt: skip
    out = work / "mission"
    killed = False
    try:
        with open(work / "mission.txt", "w", encoding="utf-8") as text:
            mission = subprocess.Popen(
                [
                    sys.executable, "-c", "from companion.cli.main import main; main()",
                    "mission", "pickup", "--config", str(CONFIG),
                    "--connect", f"udpin://127.0.0.1:{sitl.onboard_port}",
                    "--arm-bus", sitl.arm_bus, "--payload-at", PAYLOAD_AT,
                    "--place-at", ",".join(f"{v:g}" for v in PLACE_AT), "--out", str(out),
                ],
                stdout=text, stderr=subprocess.STDOUT, cwd=work,
                env=dict(os.environ, PYTHONUNBUFFERED="1"),
            )  # fmt: skip
            try:
                if fault is None:
                    began = _await_phase(sitl.output, phase, time.monotonic() + MISSION_TIMEOUT_S)
                    if began is not None and mission.poll() is None:
                        time.sleep(OFFSET_S / speed)
                        if kind == "companion_kill":
                            mission.send_signal(signal.SIGKILL)
                            killed = True
                        else:
                            _starve(mission)
                mission.wait(timeout=MISSION_TIMEOUT_S)
            finally:
                if mission.poll() is None:
                    mission.kill()
        ended = _read_truth(truth_log)  # the truth is written in blocks: up to ~0.5 s behind
        killed_at_s = ended[-1]["t_s"] if killed and ended else None
        deadline = time.monotonic() + AFTER_S
        while time.monotonic() < deadline:
            truth = _read_truth(truth_log)
            if truth and not truth[-1]["armed"] and truth[-1]["on_ground"]:
                break
            time.sleep(1.0)
    finally:
        sitl.stop()
    truth = _read_truth(truth_log)
    summary_path = out / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.exists() else None
    until_s = killed_at_s if killed else handover_s(truth)
    verdict = judge(truth, summary, PLACE_AT, _log_end_s(out), until_s, killed)
    modes, _ = px4_modes(work / "px4")
    if killed:
        outcome = "killed" if killed_at_s is None else f"killed at {killed_at_s:.1f} s"
    elif summary is None:
        outcome = "no summary"
    else:
        faults = ", ".join(f["fault"] for f in summary.get("faults", []))
        outcome = summary.get("outcome", "?") + (f" ({faults})" if faults else "")
    return Flown(
        kind, phase, verdict.safe, verdict.broken, verdict.end, verdict.touchdown_m_s,
        verdict.max_tilt_deg, verdict.payload, outcome, modes, until_s,
        time.monotonic() - wall0, work,
    )  # fmt: skip


def page(flown: list[Flown], commit: str, machine: str) -> str:
    safe = sum(f.safe for f in flown)
    lines = [
        "# Faults where PX4 reacts: the sample with the real PX4 in the loop",
        "",
        "Written by `python benchmarks/px4_fault_sample.py --write`: the PX4 SITL build "
        "(`PX4_SITL_DIR`) flying our hexacopter-with-arm physics (`sitl run --autopilot px4`, "
        f"speed {VALIDATED_SPEED:g}), `companion mission pickup` as its own process, "
        f"configs/sitl_pickup.toml, seed 1; at commit {commit} on {machine}. "
        f"{len(flown)} flights, {safe} safe by [faults.md](faults.md)'s numbers.",
        "",
        "Faults start 0.5 s into the phase: `pilot_takeover` (the ground station asks for "
        "Return), `offboard_loss` (the companion's link silent 10 s), `low_battery` (PX4's "
        "simulated battery at 6 %, COM_LOW_BAT_ACT 3), `companion_kill` (SIGKILL). PX4's "
        "modes are its ULog's `vehicle_status` (nav_state, `!` a failsafe, then the "
        "disarm; after it PX4 shows the mode last asked for again), in PX4's time, which is "
        "the truth's [s]. A link cut (offboard loss) ends in AUTO_LAND: the companion's land "
        "command once the link is back.",
        "",
        "| fault | phase | safe | outcome (companion) | end | touchdown m/s | tilt deg "
        "| payload | PX4's modes (ULog) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for f in flown:
        touchdown = "-" if f.touchdown_m_s is None else f"{f.touchdown_m_s:.2f}"
        verdict = "yes" if f.safe else "no: " + "; ".join(f.broken)
        lines.append(
            f"| {f.kind} | {f.phase} | {verdict} | {f.outcome} | {f.end} | {touchdown} | "
            f"{f.max_tilt_deg:.1f} | {f.payload} | {f.px4_modes} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="write docs/px4_fault_sample.md")
    parser.add_argument("--only", choices=sorted(FAULTS), help="fly this fault only")
    parser.add_argument("--phases", default=",".join(PHASES), help="comma-separated phases")
    parser.add_argument("--out", type=Path, help="keep each flight's logs here")
    parser.add_argument("--commit", default="the working tree", help="the commit flown")
    parser.add_argument("--machine", default=f"{platform.machine()}, {os.cpu_count()} cores")
    args = parser.parse_args()
    build = Px4Build.from_env()
    if build is None:
        sys.exit("error: set PX4_SITL_DIR to the PX4 SITL build")
    root = args.out or Path(tempfile.mkdtemp(prefix="px4-fault-sample-"))
    flown = []
    for kind in [args.only] if args.only else SAMPLE:
        for phase in args.phases.split(","):
            work = root / f"{kind}-{phase}"
            work.mkdir(parents=True, exist_ok=False)
            f = fly(build, kind, phase, work)
            flown.append(f)
            print(
                f"{kind:15} {phase:9} safe={f.safe} {f.outcome:28} {f.end:20} "
                f"wall {f.wall_s:.0f} s  {'; '.join(f.broken)}\n    PX4: {f.px4_modes}",
                flush=True,
            )
    text = page(flown, args.commit, args.machine)
    if args.write:
        (ROOT / "docs" / "px4_fault_sample.md").write_text(text, encoding="utf-8")
    print(text)
    sys.exit(0 if all(f.safe for f in flown) else 1)


if __name__ == "__main__":
    main()

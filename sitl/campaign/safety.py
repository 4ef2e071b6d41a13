"""Whether a flight ended safe, by the numbers of docs/faults.md, judged on the truth log.

:func:`judge` reads the truth's samples (``truth.jsonl`` lines as dicts: ``q`` = x y z
[m, world ENU], phi theta psi [rad, ZYX], eta1 eta2 [rad]; ``q_dot``; ``armed``, ``mode``
(PX4's mode name), ``on_ground``, ``payload_attached``, ``object_position_m``), the
mission's summary and whether its flight log read back, and returns a :class:`Verdict`:
each broken criterion one line. It never looks at what the companion believed, only at
what the vehicle did and what the summary says.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = [
    "ARM_STILL_RAD_S",
    "COMPANION_FREE_MODES",
    "DROP_HEIGHT_M",
    "PLACED_WITHIN_M",
    "TILT_MAX_DEG",
    "TOUCHDOWN_MAX_M_S",
    "Verdict",
    "handover_s",
    "judge",
]

TOUCHDOWN_MAX_M_S = 1.0
"""Largest vertical speed at a touchdown [m/s]."""
TILT_MAX_DEG = 45.0
"""Largest tilt while airborne [deg]: PX4's MPC_TILTMAX_AIR default."""
ARM_STILL_RAD_S = 0.5
"""Largest joint speed at the end [rad/s]: the arm resting or holding."""
DROP_HEIGHT_M = 0.3
"""Highest an object may be let go [m above the ground, its position in the truth]."""
JAWS_STILL_RAD = 0.05
"""The gripper opened by less than this after the object left [rad]: not a release."""
RELEASE_LOOK_S = 0.3
"""How long after the object left the gripper's motion is looked at [s]."""
PLACED_WITHIN_M = 0.10
"""An object let go within this horizontal distance of the place point counts as placed
wherever it was let go from [m]."""
COMPANION_FREE_MODES = frozenset(
    {"POSCTL", "ALTCTL", "AUTO_LOITER", "AUTO_RTL", "AUTO_LAND", "AUTO_MISSION"}
)
"""PX4 modes that fly without the companion (PX4's display names)."""
LOG_END_WITHIN_S = 1.0
"""The flight log's last row lies within this much of the truth's last sample [s]."""


@dataclass(frozen=True)
class Verdict:
    """A flight's safety: ``safe`` when ``broken`` is empty; the figures judged."""

    broken: tuple[str, ...]
    end: str
    """How it ended: ``landed``, ``with PX4 in MODE``, or what was wrong."""
    touchdown_m_s: float | None
    """The fastest touchdown's vertical speed [m/s] (None: it never touched down)."""
    max_tilt_deg: float
    """The largest tilt while airborne [deg]."""
    payload: str
    """``never held``, ``placed``, ``held`` (on the ground), ``held in the air``, ``let go
    low``, ``slipped at Z m`` (out of closed jaws), or ``let go at Z m`` (too high)."""
    end_joint_speed_rad_s: float
    """The faster joint's speed at the end [rad/s]."""

    @property
    def safe(self) -> bool:
        return not self.broken


def _tilt_deg(q: Sequence[float]) -> float:
    """The angle between body up and world up [deg], from ZYX roll and pitch."""
    c = math.cos(q[3]) * math.cos(q[4])
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def _end(last: Mapping[str, Any]) -> tuple[str, str | None]:
    """(how it ended, what is wrong with it or None)."""
    mode, armed, on_ground = last.get("mode"), last.get("armed"), last.get("on_ground")
    if on_ground and not armed:
        return "landed", None
    if not on_ground and not armed:
        return "disarmed in the air", "disarmed in the air at the end"
    if mode in COMPANION_FREE_MODES:
        return f"with PX4 in {mode}", None
    where = "on the ground" if on_ground else "in the air"
    return f"armed {where} in {mode}", f"ended armed {where} in {mode}, which needs the companion"


def _opened(truth: Sequence[Mapping[str, Any]], grasp: int, release: int) -> bool:
    """The jaws were opening when the object left them: from the grasp (sample ``grasp``,
    the first attached) to :data:`RELEASE_LOOK_S` after the object left (sample
    ``release``), the gripper moved back the way it came as it closed on the object."""
    angles = [s.get("gripper_angle_rad") for s in truth]
    before, held = angles[max(grasp - 1, 0)], angles[grasp]
    t_end = float(truth[release]["t_s"]) + RELEASE_LOOK_S
    later = [a for s, a in zip(truth[release:], angles[release:], strict=True)
             if float(s["t_s"]) <= t_end]  # fmt: skip
    if before is None or held is None or not later or later[-1] is None:
        return True  # not known: judged as let go
    closing = math.copysign(1.0, held - before)
    return (later[-1] - held) * closing < -JAWS_STILL_RAD


def _payload(
    truth: Sequence[Mapping[str, Any]], place_m: Sequence[float]
) -> tuple[str, str | None]:
    """(what became of the object, what is wrong with it or None). An object that left
    jaws that were not opening slipped out (a fault of the world, not a release): its
    height is not judged."""
    held = False
    grasp = 0
    for i in range(1, len(truth)):
        before, after = truth[i - 1], truth[i]
        if after.get("payload_attached") and not before.get("payload_attached"):
            grasp = i
        held = held or bool(before.get("payload_attached"))
        if before.get("payload_attached") and not after.get("payload_attached"):
            obj = before.get("object_position_m")
            if obj is None or math.dist(obj[:2], place_m[:2]) <= PLACED_WITHIN_M:
                continue
            height = float(obj[2])
            if not _opened(truth, grasp, i):
                return f"slipped at {height:.2f} m", None
            if height > DROP_HEIGHT_M:
                return f"let go at {height:.2f} m", (
                    f"the object was let go {height:.2f} m above the ground "
                    f"(at most {DROP_HEIGHT_M:g} m)"
                )
    last = truth[-1]
    held = held or bool(last.get("payload_attached"))
    if not held:
        return "never held", None
    if last.get("payload_attached"):
        if last.get("on_ground"):
            return "held", None
        return "held in the air", None
    obj = last.get("object_position_m")
    if obj is not None and math.dist(obj[:2], place_m[:2]) <= PLACED_WITHIN_M:
        return "placed", None
    return "let go low", None


def _flight_end_s(truth: Sequence[Mapping[str, Any]]) -> float:
    """The flight's end [s]: the disarm, when the vehicle ends disarmed (the companion's
    clean-up after it, streams given back over a lossy link, flies nothing), else the
    truth's last sample."""
    end = float(truth[-1]["t_s"])
    for sample in reversed(truth):
        if sample.get("armed"):
            break
        end = float(sample["t_s"])
    return end


def handover_s(truth: Sequence[Mapping[str, Any]]) -> float | None:
    """When PX4 last left OFFBOARD while armed [s] (the truth's mode: PX4's 1 Hz heartbeat
    with PX4 in the loop, up to a second late): from then on PX4 flies, with or without the
    companion, so its flight log need reach no further (``judge``'s ``log_until_s``); None
    when it never flew OFFBOARD."""
    handover = None
    for before, after in itertools.pairwise(truth):
        if (
            before.get("mode") == "OFFBOARD"
            and after.get("mode") != "OFFBOARD"
            and before.get("armed")
        ):
            handover = float(after["t_s"])
    return handover


def judge(
    truth: Sequence[Mapping[str, Any]],
    summary: Mapping[str, Any] | None,
    place_m: Sequence[float],
    log_end_s: float | None,
    log_until_s: float | None = None,
    killed: bool = False,
) -> Verdict:
    """The :class:`Verdict` of a flight: ``truth`` its truth-log samples in time order,
    ``summary`` its ``summary.json``, ``place_m`` the place point [m, world ENU],
    ``log_end_s`` the vehicle time of the flight log's last row [s] (None: the log did not
    read back). The log must reach the flight's end, or ``log_until_s`` [s] when the flight
    went on without the companion (PX4 flying on after it handed over, or after it was
    killed); a companion ``killed`` (kill -9) wrote no summary (``None``). See
    docs/faults.md for the criteria."""
    if not truth:
        return Verdict(("no truth log",), "unknown", None, 0.0, "unknown", 0.0)
    broken: list[str] = []
    end, wrong = _end(truth[-1])
    if wrong:
        broken.append(wrong)
    touchdowns = [
        -float(before["q_dot"][2])
        for before, after in itertools.pairwise(truth)
        if not before.get("on_ground") and after.get("on_ground")
    ]
    touchdown = max(touchdowns) if touchdowns else None
    if touchdown is not None and touchdown > TOUCHDOWN_MAX_M_S:
        broken.append(f"touched down at {touchdown:.2f} m/s (at most {TOUCHDOWN_MAX_M_S:g})")
    airborne = [_tilt_deg(s["q"]) for s in truth if not s.get("on_ground")]
    tilt = max(airborne, default=0.0)
    if tilt > TILT_MAX_DEG:
        broken.append(f"tilted {tilt:.1f} deg (at most {TILT_MAX_DEG:g})")
    joint_speed = max(abs(float(v)) for v in truth[-1]["q_dot"][6:8])
    if joint_speed > ARM_STILL_RAD_S:
        broken.append(f"the arm still moves at {joint_speed:.2f} rad/s at the end")
    payload, wrong = _payload(truth, place_m)
    if wrong:
        broken.append(wrong)
    if not killed:  # a killed companion names nothing: its killer names the kill
        outcome = None if summary is None else summary.get("outcome")
        if summary is None or not outcome:
            broken.append("the summary names no outcome")
        elif outcome == "aborted" and not summary.get("faults"):
            broken.append("aborted, but the summary names no fault")
    end_s = _flight_end_s(truth) if log_until_s is None else log_until_s
    if log_end_s is None:
        broken.append("the flight log does not read back")
    elif end_s - log_end_s > LOG_END_WITHIN_S:
        what = "the flight" if log_until_s is None else "the companion's last control"
        broken.append(f"the flight log ends {end_s - log_end_s:.1f} s before {what}")
    return Verdict(
        tuple(broken),
        end,
        touchdown,
        tilt,
        payload,
        joint_speed,
    )

"""Faults on the vehicle's MAVLink links, acted on the messages it receives and sends.

- a cut (``RunOptions.link_cut``): the onboard link silent both ways for a while;
- a lossy stretch (``link_loss``): each message on the onboard link, either way, dropped
  with a probability, drawn from a generator of its own seeded by the run's seed (a flight
  without this fault draws nothing from it, so its other noise is unchanged);
- a pilot taking over (``pilot_takeover``): a mode switch arriving on the ground-station
  link as QGroundControl sends it (COMMAND_LONG MAV_CMD_DO_SET_MODE from system 255,
  component 190), which the autopilot handles as it handles any;
- a latency spike (``link_latency``): every message on the onboard link, either way, held
  back ``delay_s`` for ``duration_s`` (a congested radio, a USB adapter's buffering), in
  order (:class:`DelayLine`: the imitation's links, and the relay of PX4's onboard link);
- a battery running low (``low_battery``, PX4 in the loop only): PX4's simulated battery
  (its ``battery_simulator``) told from the ground station to fall to a remaining charge
  within a second (PARAM_SET SIM_BAT_DRAIN 1 s, then SIM_BAT_MIN_PCT, the parameter PX4
  documents for trying its low-battery behaviour in flight); PX4's failsafe does the rest.

Each starts at a simulated time or a mission phase (:mod:`sitl.vehicle.mission_phases`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar, Generic, TypeVar

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from sitl.px4.modes import Px4Mode
from sitl.vehicle.mission_phases import FaultStart, MissionPhases, Stretch, valid_start

if TYPE_CHECKING:
    from sitl.vehicle.options import RunOptions

__all__ = [
    "GCS_COMPONENT_ID",
    "GCS_SYSTEM_ID",
    "DelayLine",
    "LinkFaults",
    "LinkLatency",
    "LinkLoss",
    "LowBattery",
    "PilotTakeover",
]

GCS_SYSTEM_ID = 255
"""QGroundControl's MAVLink system id."""
GCS_COMPONENT_ID = mavlink2.MAV_COMP_ID_MISSIONPLANNER
"""QGroundControl's component id (190)."""
TAKEOVER_MODES = ("POSCTL", "ALTCTL", "AUTO_LOITER", "AUTO_RTL", "AUTO_LAND")
"""The modes a pilot switches to."""


_T = TypeVar("_T")


class DelayLine(Generic[_T]):
    """Messages held back on a link, in order: each goes on once its delay has passed and
    never before one held earlier (a link's buffer keeps the order)."""

    def __init__(self) -> None:
        self._held: deque[tuple[float, _T]] = deque()

    def __bool__(self) -> bool:
        return bool(self._held)

    def hold(self, item: _T, now_s: float, delay_s: float) -> bool:
        """Hold ``item`` arriving at ``now_s`` [s] for ``delay_s`` [s], behind any held
        before it; False (not held: it goes on now) without a delay and with nothing held."""
        held = self._held
        if delay_s <= 0.0 and not held:
            return False
        due_s = now_s + max(delay_s, 0.0)
        if held:
            due_s = max(due_s, held[-1][0])
        held.append((due_s, item))
        return True

    def due(self, now_s: float) -> list[_T]:
        """The items whose time has come at ``now_s`` [s], in order (taken off the line)."""
        held, out = self._held, []
        while held and held[0][0] <= now_s:
            out.append(held.popleft()[1])
        return out


@dataclass(frozen=True)
class LinkLoss(Stretch):
    """``drop_fraction`` of the onboard link's messages dropped, both ways, for
    ``duration_s`` [s] from ``start``."""

    drop_fraction: float
    WHAT: ClassVar[str] = "link loss"
    STRENGTH: ClassVar[str] = "drop_fraction"


@dataclass(frozen=True)
class LinkLatency(Stretch):
    """Every message of the onboard link held back ``delay_s`` [s], both ways, for
    ``duration_s`` [s] from ``start``."""

    delay_s: float
    WHAT: ClassVar[str] = "latency spike"
    STRENGTH: ClassVar[str] = "delay_s"
    MOST: ClassVar[float] = 2.0


@dataclass(frozen=True)
class PilotTakeover:
    """At ``start``, the ground station asks for ``mode`` (PX4's display name)."""

    start: FaultStart
    mode: str = "POSCTL"

    def __post_init__(self) -> None:
        if not valid_start(self.start):
            raise ValueError(f"a takeover starts at a time >= 0 or a phase, got {self.start!r}")
        if self.mode not in TAKEOVER_MODES:
            raise ValueError(f"mode must be one of {', '.join(TAKEOVER_MODES)}, got {self.mode!r}")


@dataclass(frozen=True)
class LowBattery:
    """At ``start``, PX4's simulated battery falls to ``remaining_pct`` [%] of its charge
    within a second. The default, 6 %, lies between PX4's critical (BAT_CRIT_THR 7 %) and
    emergency (BAT_EMERGEN_THR 5 %) levels: with COM_LOW_BAT_ACT 3, PX4 returns."""

    start: FaultStart
    remaining_pct: float = 6.0

    def __post_init__(self) -> None:
        if not valid_start(self.start):
            raise ValueError(f"a low battery starts at a time >= 0 or a phase, got {self.start!r}")
        if not 0.0 <= self.remaining_pct < 100.0:
            raise ValueError(f"remaining_pct must be 0 to 100 %, got {self.remaining_pct!r}")

    def parameters(self) -> dict[str, float]:
        """PX4's battery_simulator parameters that make it so, in the order to set them."""
        return {"SIM_BAT_DRAIN": 1.0, "SIM_BAT_MIN_PCT": self.remaining_pct}


class LinkFaults:
    """The link faults of a run: what is dropped, and the pilot's command when it is due."""

    def __init__(
        self,
        phases: MissionPhases,
        seed: int,
        *,
        cut: tuple[FaultStart, float] | None = None,
        loss: LinkLoss | None = None,
        takeover: PilotTakeover | None = None,
        battery: LowBattery | None = None,
        latency: LinkLatency | None = None,
        autopilot_system_id: int = 1,
    ) -> None:
        self._phases = phases
        self._cut = cut
        self._loss = loss
        self._takeover = takeover
        self._battery = battery
        self._latency = latency
        self._system_id = autopilot_system_id
        self._rng = np.random.default_rng([seed, 0x10551])
        self._gcs = mavlink2.MAVLink(None, GCS_SYSTEM_ID, GCS_COMPONENT_ID)

    @classmethod
    def of_run(
        cls, options: RunOptions, phases: MissionPhases, autopilot_system_id: int = 1
    ) -> LinkFaults:
        """The link faults ``options`` asks for (its seed, cut, loss, takeover and battery)."""
        return cls(
            phases,
            options.seed,
            cut=options.link_cut,
            loss=options.link_loss,
            takeover=options.pilot_takeover,
            battery=options.low_battery,
            latency=options.link_latency,
            autopilot_system_id=autopilot_system_id,
        )

    def cut(self, now_s: float) -> bool:
        """The onboard link is cut at ``now_s`` [s]."""
        return self._cut is not None and self._phases.within(*self._cut, now_s)

    def drops(self, link: str, now_s: float) -> bool:
        """Drop one message on ``link`` at ``now_s`` [s]: the link is cut, or lossy and the
        draw says so."""
        if link != "onboard":
            return False
        if self.cut(now_s):
            return True
        loss = self._loss
        if loss is None or not self._phases.within(loss.start, loss.duration_s, now_s):
            return False
        return bool(self._rng.random() < loss.drop_fraction)

    @property
    def takeover_pending(self) -> bool:
        """The pilot's takeover is still to come (:meth:`takeover` looks at every step)."""
        return self._takeover is not None

    def delay_s(self, link: str, now_s: float) -> float:
        """The extra latency of a message on ``link`` at ``now_s`` [s]: a spike's delay
        while it lasts, else 0."""
        latency = self._latency
        if link != "onboard" or latency is None:
            return 0.0
        return (
            latency.delay_s
            if self._phases.within(latency.start, latency.duration_s, now_s)
            else 0.0
        )

    def takeover(self, now_s: float) -> mavlink2.MAVLink_message | None:
        """The ground station's mode command, once, when its time has come [s]."""
        takeover = self._takeover
        if takeover is None:
            return None
        if not self._phases.reached(takeover.start, now_s):
            return None
        self._takeover = None
        mode = Px4Mode[takeover.mode]
        command = mavlink2.MAVLink_command_long_message(
            self._system_id, 1, mavlink2.MAV_CMD_DO_SET_MODE, 0,
            float(mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED),
            float(mode.main_mode), float(mode.sub_mode), 0.0, 0.0, 0.0, 0.0,
        )  # fmt: skip
        (received,) = self._gcs.parse_buffer(command.pack(self._gcs))
        return received

    def battery(self, now_s: float) -> list[mavlink2.MAVLink_message]:
        """The ground station's PARAM_SETs of a low battery, once, when its time has come
        [s]; else none."""
        battery = self._battery
        if battery is None:
            return []
        if not self._phases.reached(battery.start, now_s):
            return []
        self._battery = None
        return [
            mavlink2.MAVLink_param_set_message(
                self._system_id, 1, name.encode(), value, mavlink2.MAV_PARAM_TYPE_REAL32
            )
            for name, value in battery.parameters().items()
        ]

"""Faults on the vehicle's servo bus, each started at a simulated time or a mission phase
(:mod:`sitl.vehicle.mission_phases`):

- a servo gone silent (``RunOptions.servo_silent``): it carries out instructions but never
  answers again (a broken TX line);
- a servo's hardware error (``servo_error``): the bit in its Hardware Error Status(70),
  with the shutdown its Shutdown(63) selects
  (:meth:`sitl.servo.xm430.XM430Servo.inject_hardware_error`);
- a servo rebooting by itself (``servo_reboot``: its supply dipped, a brown-out): its RAM
  back at the defaults, torque off (:meth:`sitl.servo.xm430.XM430Servo.reboot`), and no
  answer while it boots (``boot_s``); then it answers again, limp until torque is enabled;
- corrupted replies for a while (``bus_corruption``): each reply's CRC broken with a
  probability (electrical noise on the line), drawn from the responder's generator seeded
  by the run's seed (a flight without this fault draws nothing from it).

Hosts (the imitation's :class:`~sitl.vehicle.runner.SitlVehicle`, PX4 in the loop) call
:meth:`ServoBusFaults.update` after every plant step; it touches the bus only when a fault
starts or ends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from sitl.servo import Faults
from sitl.servo.responder import RespondingBus
from sitl.vehicle.mission_phases import FaultStart, MissionPhases, Stretch, valid_start

if TYPE_CHECKING:
    from sitl.vehicle.options import RunOptions

__all__ = ["BusCorruption", "ServoBusFaults", "ServoReboot", "bus_faults"]


@dataclass(frozen=True)
class BusCorruption(Stretch):
    """``corrupt_fraction`` of the servos' replies sent with a broken CRC for
    ``duration_s`` [s] from ``start``."""

    corrupt_fraction: float
    WHAT: ClassVar[str] = "corruption"
    STRENGTH: ClassVar[str] = "corrupt_fraction"


@dataclass(frozen=True)
class ServoReboot:
    """Servo ``servo_id`` reboots at ``start`` and answers nothing for ``boot_s`` [s]."""

    servo_id: int
    start: FaultStart
    boot_s: float

    def __post_init__(self) -> None:
        if not valid_start(self.start):
            raise ValueError(f"a servo reboot starts at a time >= 0 or a phase, got {self.start!r}")
        if not (math.isfinite(self.boot_s) and 0.0 < self.boot_s <= 10.0):
            raise ValueError(f"boot_s must be in (0, 10], got {self.boot_s!r}")


def bus_faults(
    options: RunOptions, silent_ids: frozenset[int] = frozenset(), corrupt_fraction: float = 0.0
) -> Faults:
    """The servo bus's faults: the run's reply delay, servos ``silent_ids`` silent, replies
    corrupted at ``corrupt_fraction``, the corruption drawn from the run's seed."""
    return Faults(
        silent_ids=silent_ids,
        crc_corruption_rate=corrupt_fraction,
        reply_delay_s=options.servo_reply_delay_s,
        seed=options.seed,
    )


class ServoBusFaults:
    """The servo bus faults of a run (``options``: a :class:`~sitl.vehicle.options.RunOptions`),
    started when their moment comes in ``phases``."""

    def __init__(self, options: RunOptions, phases: MissionPhases) -> None:
        self._options = options
        self._phases = phases
        self._silent: tuple[int, FaultStart] | None = options.servo_silent
        self._error = options.servo_error
        self._corruption: BusCorruption | None = options.bus_corruption
        self._reboot: ServoReboot | None = options.servo_reboot
        self._silent_id: int | None = None
        self._booting_id: int | None = None
        self._corrupting = False
        self.pending = self._any_pending()
        """Some fault has yet to start or end (else :meth:`update` returns at once)."""

    def faults(self) -> Faults:
        """The bus's faults now (:func:`bus_faults`)."""
        corruption = self._corruption
        fraction = corruption.corrupt_fraction if corruption and self._corrupting else 0.0
        silent = frozenset(i for i in (self._silent_id, self._booting_id) if i is not None)
        return bus_faults(self._options, silent, fraction)

    def update(self, now_s: float, bus: RespondingBus) -> None:
        """Start or end what is due at simulated time ``now_s`` [s] on ``bus``."""
        if not self.pending:
            return
        changed = False
        silent = self._silent
        if silent is not None and self._phases.reached(silent[1], now_s):
            self._silent_id, self._silent = silent[0], None
            changed = True
        error = self._error
        if error is not None and self._phases.reached(error.start, now_s):
            with bus.lock:
                bus.servos[error.servo_id].inject_hardware_error(error.bits)
            self._error = None
        reboot = self._reboot
        if reboot is not None and self._phases.reached(reboot.start, now_s):
            start_s = self._phases.start_s(reboot.start)
            assert start_s is not None
            booting = now_s < start_s + reboot.boot_s
            if booting and self._booting_id is None:
                with bus.lock:
                    bus.servos[reboot.servo_id].reboot()
                self._booting_id = reboot.servo_id
                changed = True
            elif not booting:
                self._booting_id, self._reboot = None, None
                changed = True
        corruption = self._corruption
        if corruption is not None and self._phases.reached(corruption.start, now_s):
            start_s = self._phases.start_s(corruption.start)
            assert start_s is not None
            active = now_s < start_s + corruption.duration_s
            if active != self._corrupting:
                self._corrupting = active
                changed = True
            if not active:
                self._corruption = None
        if changed:
            bus.set_faults(self.faults())
        self.pending = self._any_pending()

    def _any_pending(self) -> bool:
        return any(
            fault is not None
            for fault in (self._silent, self._error, self._corruption, self._reboot)
        )

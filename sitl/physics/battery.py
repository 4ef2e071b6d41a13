"""The truth battery and what its voltage does to the rotors (truth only: the companion sees
only the voltage and current the vehicle streams).

A lithium-polymer pack of ``cells`` cells in series:

- open-circuit voltage from the charge left, per cell, by a typical LiPo discharge curve
  (:data:`OCV_CURVE`: 4.20 V full, 3.84 V at half charge, 3.27 V empty);
- terminal voltage ``V = OCV - I R`` with the pack's internal resistance R [ohm], so that a
  heavier load (the grasp's payload) drops it at once;
- current ``I = P / V`` for the electrical power P the rotors draw, P = k sum(T_i^1.5)
  (momentum theory: ideal induced power T^1.5 / sqrt(2 rho A), divided by the figure of
  merit and the motor and ESC efficiency, gives k; :data:`ROTOR_POWER_W_PER_N1_5`) plus
  the avionics' :data:`AVIONICS_POWER_W`; V and I solve V^2 - OCV V + P R = 0;
- thrust per command following the voltage as a brushless motor's does: the command sets
  the duty cycle, the rotor speed goes with duty x V, the thrust with its square, so the
  thrust a command makes is ``(V / V_ref)^2`` times what it makes at the reference voltage
  ``V_ref = cells x`` :data:`REFERENCE_CELL_V`, at which ``vehicle.rotors
  .max_thrust_per_rotor_n`` (times ``plant.thrust_mismatch``) holds.

The charge drawn is counted per step (coulomb counting). Pure: no I/O, no clock. The pack's
constants and state are one float64 buffer whose arithmetic is the truth plant's compiled
step's (:mod:`sitl.vehicle_step`: :func:`~sitl.vehicle_step.
battery_draw`), which feeds the rotors from it inside its step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from companion.compiled import twin
from sitl import vehicle_step

__all__ = [
    "AVIONICS_POWER_W",
    "OCV_CURVE",
    "REFERENCE_CELL_V",
    "ROTOR_POWER_W_PER_N1_5",
    "BatteryReading",
    "LipoPack",
]

OCV_CURVE: tuple[tuple[float, float], ...] = (
    (0.00, 3.27),
    (0.05, 3.61),
    (0.10, 3.69),
    (0.20, 3.73),
    (0.30, 3.77),
    (0.40, 3.80),
    (0.50, 3.84),
    (0.60, 3.87),
    (0.70, 3.93),
    (0.80, 4.01),
    (0.90, 4.09),
    (1.00, 4.20),
)
"""(state of charge [-], open-circuit cell voltage [V]) of a LiPo cell at rest, linear
between the points."""

REFERENCE_CELL_V = 3.85
"""Cell voltage at which the rotors' rated thrust holds [V] (a pack near half charge under a
hover load: motor data sheets quote thrust at a nominal pack voltage)."""

ROTOR_POWER_W_PER_N1_5 = 9.0
"""Electrical power per rotor per (thrust [N])^1.5 [W / N^1.5]: 1 / sqrt(2 rho A) = 3.6 for a
10 cm rotor at sea level, over a figure of merit of 0.6 and 70 % motor and ESC efficiency
(a 1.5 kg hexacopter hovers on about 220 W)."""

AVIONICS_POWER_W = 5.0
"""Power the flight controller, companion and receivers draw [W]."""

_STEP = twin(vehicle_step)
"""The pack's arithmetic: :mod:`sitl.vehicle_step`, compiled where built."""


@dataclass(frozen=True)
class BatteryReading:
    """What a power module measures of the pack now."""

    voltage_v: float
    """Terminal voltage [V]."""
    current_a: float
    """Current drawn [A]."""
    remaining: float
    """Charge left, 0 to 1 [-]."""


class LipoPack:
    """A LiPo pack feeding the rotors (module docstring).

    Parameters
    ----------
    cells : int
        Cells in series.
    capacity_ah : float
        Charge of the full pack [A h].
    resistance_ohm : float
        Internal resistance of the pack (cells, wiring, connectors) [ohm].
    start_charge : float
        State of charge at the start, in (0, 1] [-].
    """

    def __init__(
        self, cells: int, capacity_ah: float, resistance_ohm: float, start_charge: float
    ) -> None:
        if cells < 1 or not capacity_ah > 0.0 or not resistance_ohm >= 0.0:
            raise ValueError("need cells >= 1, capacity_ah > 0 and resistance_ohm >= 0")
        if not 0.0 < start_charge <= 1.0:
            raise ValueError(f"start_charge must be in (0, 1], got {start_charge}")
        self.cells = cells
        self.capacity_ah = capacity_ah
        self.resistance_ohm = resistance_ohm
        self.reference_v = cells * REFERENCE_CELL_V
        constants = (
            cells,
            capacity_ah,
            resistance_ohm,
            self.reference_v,
            AVIONICS_POWER_W,
            ROTOR_POWER_W_PER_N1_5,
        )
        self.buffer = vehicle_step.battery_buffer(constants, start_charge, OCV_CURVE)
        """Constants and state, as :func:`~sitl.vehicle_step.battery_buffer`
        lays them out (the truth plant's step draws from it)."""
        self.buffer[vehicle_step.BATTERY_VOLTAGE] = self.open_circuit_v()

    @classmethod
    def of(cls, section: Any) -> LipoPack | None:
        """The pack a scenario's ``plant.battery`` section describes (its ``cells``,
        ``capacity_ah``, ``resistance_ohm``, ``start_charge``), or None when it has none."""
        if section is None:
            return None
        return cls(section.cells, section.capacity_ah, section.resistance_ohm, section.start_charge)

    @property
    def charge(self) -> float:
        """State of charge now [-]."""
        return self.buffer[vehicle_step.BATTERY_CHARGE]

    @property
    def voltage_v(self) -> float:
        """Terminal voltage now [V] (the open-circuit voltage until the first draw)."""
        return self.buffer[vehicle_step.BATTERY_VOLTAGE]

    @property
    def current_a(self) -> float:
        """Current drawn over the last step [A] (0 until the first draw)."""
        return self.buffer[vehicle_step.BATTERY_CURRENT]

    def open_circuit_v(self) -> float:
        """Pack voltage at rest at the present charge [V] (:data:`OCV_CURVE`)."""
        return _STEP.open_circuit_v(self.buffer)

    @property
    def thrust_factor(self) -> float:
        """Thrust a motor command makes now over what it makes at the reference voltage
        [-]: ``(V / V_ref)^2``."""
        ratio = self.voltage_v / self.reference_v
        return ratio * ratio

    def draw(self, rotor_thrusts_n: list[float], dt_s: float) -> None:
        """Feed the rotors producing ``rotor_thrusts_n`` [N] (and the avionics) for ``dt_s``
        [s]: the terminal voltage and current under that load (V^2 - OCV V + P R = 0, the
        larger root; beyond the pack's maximum power OCV^2 / 4R the voltage collapses to
        OCV / 2), then the charge drawn."""
        _STEP.battery_draw(self.buffer, rotor_thrusts_n, dt_s)

    def reading(self) -> BatteryReading:
        """The pack's terminal voltage, current and charge now."""
        return BatteryReading(self.voltage_v, self.current_a, self.charge)

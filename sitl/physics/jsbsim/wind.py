"""Wind and turbulence of the JSBSim backend, set through JSBSim's atmosphere properties.

The wind reaches the vehicle through the airframe's linear drag, which JSBSim evaluates
on the velocity relative to the air ``v - w`` with ``w = atmosphere/total-wind-*`` (steady
wind + turbulence; :mod:`sitl.physics.jsbsim.airframe`). JSBSim's rotational turbulence
(``atmosphere/[pqr]-turb-rad_sec``) drives no force here: the airframe has no
aerodynamic moment model.

Turbulence ``"milspec"`` is JSBSim's Dryden model after MIL-F-8785C / MIL-HDBK-1797
(``atmosphere/turb-type`` = 3). Below 1000 ft its intensity depends only on the wind speed
at 20 ft (sigma_w = 0.1 W20, sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h)^0.4, h in
ft clipped at 10 ft) and its scale lengths on the height; it is zero when the airspeed is
zero (the filter time constants are L / V). JSBSim keeps the filter states in
function-static variables: plants in one process share them. The Tustin variant is not
offered: it divides by tan(dt / 2 tau) and the plant's zero-dt force refresh would make
it NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

__all__ = ["MILSPEC_SEVERITY", "TurbulenceKind", "Wind"]

TurbulenceKind = Literal["none", "milspec"]

MILSPEC_SEVERITY = 3
"""JSBSim's probability-of-exceedance index for the Dryden model (1e-3, "moderate"); it
only matters above 1000 ft, far above any flight of this project."""

_FT_M = 0.3048
_TURB_TYPE = {"none": 0, "milspec": 3}


@dataclass(frozen=True)
class Wind:
    """Steady wind (both backends) and turbulence (JSBSim).

    Attributes
    ----------
    velocity_enu_m_s : tuple of 3 float
        Steady wind, the air's velocity over the ground, world ENU [m/s] (x east, y north,
        z up): (3, 0, 0) blows toward the east.
    turbulence : {"none", "milspec"}
        Turbulence model (module docstring).
    windspeed_20ft_m_s : float
        MIL-F-8785C wind speed at 20 ft [m/s], the turbulence intensity (light about 7.7,
        moderate 15, severe 23 m/s in the standard; 0 disables it).
    seed : int
        Seed of JSBSim's random generator (``simulation/randomseed``).
    """

    velocity_enu_m_s: tuple[float, ...] = (0.0, 0.0, 0.0)
    turbulence: TurbulenceKind = "none"
    windspeed_20ft_m_s: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        v = tuple(float(c) for c in self.velocity_enu_m_s)
        if len(v) != 3 or not all(math.isfinite(c) for c in v):
            raise ValueError(f"velocity_enu_m_s must be 3 finite values, got {v!r}")
        object.__setattr__(self, "velocity_enu_m_s", v)
        if self.turbulence not in _TURB_TYPE:
            raise ValueError(
                f"turbulence must be one of {sorted(_TURB_TYPE)}, got {self.turbulence!r}"
            )
        if not (math.isfinite(self.windspeed_20ft_m_s) and self.windspeed_20ft_m_s >= 0.0):
            raise ValueError(
                f"windspeed_20ft_m_s must be finite and >= 0, got {self.windspeed_20ft_m_s!r}"
            )
        if self.turbulence != "none" and self.windspeed_20ft_m_s == 0.0:
            raise ValueError("turbulence needs windspeed_20ft_m_s > 0 (its intensity)")

    @classmethod
    def from_text(
        cls,
        wind: str | None,
        turbulence_m_s: float,
        seed: int = 0,
        steady_m_s: tuple[float, ...] = (0.0, 0.0, 0.0),
    ) -> Wind | None:
        """The wind of the command lines' ``--wind E,N,U`` [m/s] and ``--turbulence W20``
        [m/s] options, the steady wind ``steady_m_s`` (the scenario's ``plant.wind_m_s``)
        where ``--wind`` is absent; None when neither option is given (the scenario's wind
        applies). Raises ``ValueError`` with the reason."""
        if wind is None and turbulence_m_s == 0.0:
            return None
        if wind is None:
            velocity = tuple(steady_m_s)
        else:
            try:
                velocity = tuple(float(v) for v in wind.split(","))
            except ValueError:
                raise ValueError(f"--wind needs E,N,U in m/s, got {wind!r}") from None
            if len(velocity) != 3:
                raise ValueError(f"--wind needs three values E,N,U in m/s, got {wind!r}")
        return cls(
            velocity_enu_m_s=velocity,
            turbulence="milspec" if turbulence_m_s > 0.0 else "none",
            windspeed_20ft_m_s=turbulence_m_s,
            seed=seed,
        )

    @property
    def calm(self) -> bool:
        """No wind and no turbulence."""
        return self.velocity_enu_m_s == (0.0, 0.0, 0.0) and self.turbulence == "none"

    def properties(self) -> dict[str, float]:
        """The JSBSim property values [English units] that set this wind."""
        east, north, up = self.velocity_enu_m_s
        props = {
            "atmosphere/wind-north-fps": north / _FT_M,
            "atmosphere/wind-east-fps": east / _FT_M,
            "atmosphere/wind-down-fps": -up / _FT_M,
            "atmosphere/turb-type": float(_TURB_TYPE[self.turbulence]),
            "simulation/randomseed": float(self.seed),
        }
        if self.turbulence == "milspec":
            props["atmosphere/turbulence/milspec/windspeed_at_20ft_AGL-fps"] = (
                self.windspeed_20ft_m_s / _FT_M
            )
            props["atmosphere/turbulence/milspec/severity"] = float(MILSPEC_SEVERITY)
        return props

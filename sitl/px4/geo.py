"""The vehicle's geodetic reference: local NED <-> latitude / longitude / altitude.

PX4 reports GLOBAL_POSITION_INT and HOME_POSITION in WGS-84 degrees and metres AMSL. The
simulated world is flat, so positions map with the local flat-earth approximation about
a fixed reference point (the world origin): north and east metres become degrees through
the radius of the Earth, altitude adds up. Over the few hundred metres of a simulated
flight the error of this approximation (against WGS-84 geodesy) is below a centimetre.
The default reference is PX4 SITL's default home (PX4_HOME_LAT/LON/ALT, Zurich).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["EARTH_RADIUS_M", "GeoReference"]

EARTH_RADIUS_M = 6_371_000.0
"""Mean Earth radius [m] of the flat-earth approximation."""


@dataclass(frozen=True)
class GeoReference:
    """Latitude [deg], longitude [deg] and altitude AMSL [m] of the world origin."""

    latitude_deg: float = 47.397742
    longitude_deg: float = 8.545594
    altitude_amsl_m: float = 488.0

    def __post_init__(self) -> None:
        if not (-89.0 <= self.latitude_deg <= 89.0 and -180.0 <= self.longitude_deg <= 180.0):
            raise ValueError(
                f"reference must lie within +-89 deg latitude and +-180 deg longitude, "
                f"got {self.latitude_deg!r}, {self.longitude_deg!r}"
            )
        if not math.isfinite(self.altitude_amsl_m):
            raise ValueError(f"altitude_amsl_m must be finite, got {self.altitude_amsl_m!r}")

    def global_from_ned(
        self, north_m: float, east_m: float, down_m: float
    ) -> tuple[float, float, float]:
        """(latitude [deg], longitude [deg], altitude AMSL [m]) of a local NED point [m]."""
        lat = self.latitude_deg + math.degrees(north_m / EARTH_RADIUS_M)
        lon = self.longitude_deg + math.degrees(
            east_m / (EARTH_RADIUS_M * math.cos(math.radians(self.latitude_deg)))
        )
        return lat, lon, self.altitude_amsl_m - down_m

    def ned_from_global(
        self, latitude_deg: float, longitude_deg: float, altitude_amsl_m: float
    ) -> tuple[float, float, float]:
        """Local NED point [m] of a geodetic position (inverse of :meth:`global_from_ned`)."""
        north = math.radians(latitude_deg - self.latitude_deg) * EARTH_RADIUS_M
        east = (
            math.radians(longitude_deg - self.longitude_deg)
            * EARTH_RADIUS_M
            * math.cos(math.radians(self.latitude_deg))
        )
        return north, east, self.altitude_amsl_m - altitude_amsl_m

"""The real PX4 built for SITL: starting it, and PX4 flying its own SIH physics
(``sitl sih``); PX4 flying our physics is :mod:`sitl.hil`.

- :mod:`~sitl.px4_sitl.launcher`: a PX4 SITL build started on a free instance's ports and
  waited for (:class:`Px4Build`, :class:`Px4Sitl`, :func:`free_instance`);
- :mod:`~sitl.px4_sitl.sih`: PX4's SIH vehicle matched to a scenario (:func:`sih_parameters`);
- :mod:`~sitl.px4_sitl.mocap`: motion capture for SIH (:class:`MocapFeeder`);
- :mod:`~sitl.px4_sitl.sih_host`: the host behind ``sitl sih`` (:class:`SihHost`).
"""

from typing import TYPE_CHECKING

from companion.lazy import lazy_attributes

__all__ = [
    "MocapFeeder",
    "Px4Build",
    "Px4BuildError",
    "Px4NotReadyError",
    "Px4Ports",
    "Px4Sitl",
    "SihHost",
    "SihMismatchError",
    "free_instance",
    "release_instance",
    "sih_parameters",
]

_HOME = {
    "MocapFeeder": "sitl.px4_sitl.mocap",
    "Px4Build": "sitl.px4_sitl.launcher",
    "Px4BuildError": "sitl.px4_sitl.launcher",
    "Px4NotReadyError": "sitl.px4_sitl.launcher",
    "Px4Ports": "sitl.px4_sitl.launcher",
    "Px4Sitl": "sitl.px4_sitl.launcher",
    "SihHost": "sitl.px4_sitl.sih_host",
    "SihMismatchError": "sitl.px4_sitl.sih",
    "free_instance": "sitl.px4_sitl.launcher",
    "release_instance": "sitl.px4_sitl.launcher",
    "sih_parameters": "sitl.px4_sitl.sih",
}
"""Where each public name lives (:mod:`companion.lazy`)."""

if TYPE_CHECKING:
    from sitl.px4_sitl.launcher import (
        Px4Build,
        Px4BuildError,
        Px4NotReadyError,
        Px4Ports,
        Px4Sitl,
        free_instance,
        release_instance,
    )
    from sitl.px4_sitl.mocap import MocapFeeder
    from sitl.px4_sitl.sih import SihMismatchError, sih_parameters
    from sitl.px4_sitl.sih_host import SihHost

__getattr__ = lazy_attributes(__name__, _HOME)

"""The offline simulator (``sitl sim``, ``sitl compare``): the companion's math against the
truth plant in one loop, without links, to reproduce the paper's results.

- :mod:`~sitl.offline.simulation`: the closed loop (:func:`simulate`, :class:`SimOptions`);
- :mod:`~sitl.offline.trajectory`: the paper's desired trajectory (:class:`PaperSinusoid`);
- :mod:`~sitl.offline.results`, :mod:`~sitl.offline.plots`: what a run writes and draws;
- :mod:`~sitl.offline.authority`: the vehicle's control authority at hover
  (``sitl authority``).
"""

from typing import TYPE_CHECKING

from companion.lazy import lazy_attributes

__all__ = [
    "Authority",
    "PaperSinusoid",
    "SimOptions",
    "SimResult",
    "hover_authority",
    "simulate",
]

_HOME = {
    "Authority": "sitl.offline.authority",
    "PaperSinusoid": "sitl.offline.trajectory",
    "SimOptions": "sitl.offline.simulation",
    "SimResult": "sitl.offline.simulation",
    "hover_authority": "sitl.offline.authority",
    "simulate": "sitl.offline.simulation",
}
"""Where each public name lives (:mod:`companion.lazy`)."""

if TYPE_CHECKING:
    from sitl.offline.authority import Authority, hover_authority
    from sitl.offline.simulation import SimOptions, SimResult, simulate
    from sitl.offline.trajectory import PaperSinusoid

__getattr__ = lazy_attributes(__name__, _HOME)

"""The flight's records: the CSV flight log, its MCAP twin, PX4's ULog merged into it and
the live view.

- :mod:`~companion.logs.columns`: a cycle's row in preallocated binary columns, and the
  columns file the flight writes them to a block at a time;
- :mod:`~companion.logs.flightlog`: one CSV row per control cycle (written from the
  columns), the events and the timing beside it (:class:`FlightLogWriter`,
  :func:`read_flight_log`);
- :mod:`~companion.logs.mcap_log`: the same cycles and events as MCAP, Protobuf under
  Foxglove's schemas (:class:`FlightLogWithMcap`, :func:`describe_mcap`);
- :mod:`~companion.logs.ulog_mcap`: PX4's ULog merged into the MCAP (:func:`add_ulog`);
- :mod:`~companion.logs.live_view`: the MCAP's channels served live to Foxglove
  (:class:`LiveView`).
"""

from typing import TYPE_CHECKING

from companion.lazy import lazy_attributes

__all__ = [
    "ArmGeometry",
    "CycleRecord",
    "FlightLog",
    "FlightLogError",
    "FlightLogWithMcap",
    "FlightLogWriter",
    "LiveView",
    "LiveViewError",
    "McapLogWriter",
    "UlogError",
    "add_ulog",
    "describe_mcap",
    "read_flight_log",
]

_HOME = {
    "ArmGeometry": "companion.logs.mcap_log",
    "CycleRecord": "companion.logs.flightlog",
    "FlightLog": "companion.logs.flightlog",
    "FlightLogError": "companion.logs.flightlog",
    "FlightLogWithMcap": "companion.logs.mcap_log",
    "FlightLogWriter": "companion.logs.flightlog",
    "LiveView": "companion.logs.live_view",
    "LiveViewError": "companion.logs.live_view",
    "McapLogWriter": "companion.logs.mcap_log",
    "UlogError": "companion.logs.ulog_mcap",
    "add_ulog": "companion.logs.ulog_mcap",
    "describe_mcap": "companion.logs.mcap_log",
    "read_flight_log": "companion.logs.flightlog",
}
"""Where each public name lives (:mod:`companion.lazy`)."""

if TYPE_CHECKING:
    from companion.logs.flightlog import (
        CycleRecord,
        FlightLog,
        FlightLogError,
        FlightLogWriter,
        read_flight_log,
    )
    from companion.logs.live_view import LiveView, LiveViewError
    from companion.logs.mcap_log import ArmGeometry, FlightLogWithMcap, McapLogWriter, describe_mcap
    from companion.logs.ulog_mcap import UlogError, add_ulog

__getattr__ = lazy_attributes(__name__, _HOME)

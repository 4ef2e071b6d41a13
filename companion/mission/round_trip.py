"""How late the link is: the round trip of a pose down and a command up, in vehicle time
(pure, no clock).

The control loop closes its position loop on PX4's poses and PX4 flies the setpoints it
sends back. A link that holds messages back (a router's or a radio's buffer filling, a
USB-serial adapter's latency) leaves the poses evenly spaced: no gap shows to the
loop-period watch (:mod:`companion.mission.loop_period`), yet every pose is old when the loop
flies on it and every setpoint old when PX4 flies it. Measured with PX4 in the loop, 0.1 s
each way took the vehicle to 41 deg of tilt in the excitation and 0.3 s crashed it
(docs/faults.md).

The watch measures the delay with MAVLink's TIMESYNC. Every ``period_s`` of vehicle time the
app sends a request whose ``ts1`` is the vehicle time of the newest pose [ns]; PX4 answers
with ``tc1``, its clock when the request came in [ns], and ``ts1`` echoed
(``MavlinkTimesync::handle_message``; PX4's clock is the poses' clock). ``tc1 - ts1`` is then
the pose's age when the request left plus the request's way up: the round trip, in vehicle
time, without a clock of the companion's and at any simulation speed. A request lost gives no
reply (a lossy link is no false alarm); a reply whose ``ts1`` is not one of ours (an answer to
another component) is not counted.

A reply with a round trip over ``max_round_trip_s`` is late; ``late_replies`` late replies in a
row are the ``link_latency`` fault (:mod:`companion.mission.failsafe`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

__all__ = ["RoundTrip", "RoundTripWatch"]


@dataclass(frozen=True)
class RoundTrip:
    """One reply's round trip."""

    round_trip_s: float
    """Vehicle time from the newest pose when the request left to PX4 taking it [s]."""
    fault: str | None
    """Why the link is too slow while the last ``late_replies`` replies or more were all
    late; None otherwise."""


class RoundTripWatch:
    """Times TIMESYNC requests and their replies in vehicle time.

    Parameters
    ----------
    max_round_trip_s
        Longest round trip the loops fly on [s].
    period_s
        Vehicle time between two requests [s].
    late_replies
        Late replies in a row that make the fault.
    """

    def __init__(
        self, max_round_trip_s: float, period_s: float = 0.05, late_replies: int = 3
    ) -> None:
        if not (max_round_trip_s > 0.0 and period_s > 0.0 and late_replies >= 1):
            raise ValueError("max_round_trip_s and period_s must be > 0, late_replies >= 1")
        self.max_round_trip_s = max_round_trip_s
        self.period_ns = round(period_s * 1e9)
        self.late_replies = late_replies
        self.round_trips_s: list[float] = []
        """Every reply's round trip, in order [s]."""
        self._pending: deque[int] = deque(maxlen=16)
        """``ts1`` of the requests not answered yet [ns] (the oldest forgotten: lost)."""
        self._next_ns = 0
        self._late = 0

    def request(self, pose_us: int) -> int | None:
        """The ``ts1`` [ns] of a request to send now, the newest pose being of vehicle time
        ``pose_us`` [us]; None while the next is not due."""
        t_ns = pose_us * 1000
        if t_ns < self._next_ns:
            return None
        self._next_ns = t_ns + self.period_ns
        self._pending.append(t_ns)
        return t_ns

    def reply(self, tc1_ns: int, ts1_ns: int) -> RoundTrip | None:
        """A TIMESYNC reply; None for one not answering a pending request of ours."""
        try:
            self._pending.remove(ts1_ns)
        except ValueError:
            return None
        round_trip_s = (tc1_ns - ts1_ns) * 1e-9
        self.round_trips_s.append(round_trip_s)
        if round_trip_s <= self.max_round_trip_s:
            self._late = 0
            return RoundTrip(round_trip_s, None)
        self._late += 1
        if self._late < self.late_replies:
            return RoundTrip(round_trip_s, None)
        return RoundTrip(
            round_trip_s,
            f"the link's round trip {round_trip_s * 1e3:.0f} ms over the "
            f"{self.max_round_trip_s * 1e3:.0f} ms limit in {self._late} replies in a row",
        )

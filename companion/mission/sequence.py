"""The flight around the pickup as a pure state machine: arming, PX4's take-off, the
OFFBOARD handover, the pickup, PX4's landing, and the reaction to each aborting fault.

Events in, commands out; no I/O, no clock, times are vehicle time [s]. The app
(:class:`~companion.mission.app.PickupApp`) gives :meth:`FlightSequence.next` what it observes after
every control cycle (:class:`Observation`) and carries out the command it gets back
(:data:`Command`); a command that waits on PX4 (arm, take-off, mode, land) is answered with
:meth:`FlightSequence.done`, its refusal as the error text. :data:`WAIT` means "nothing to do
before the next control cycle". A stage that cannot end raises :class:`SequenceFailed`.

The pickup, from the ground (:meth:`FlightSequence.begin`):

===================  ==========================================  ======================
stage                until                                       then
===================  ==========================================  ======================
``estimate``         a state estimate (at most 2 s)              note the ground height;
                                                                 refuse an unreachable
                                                                 plan; ``servos`` (when
                                                                 checked) or ``arm``
``servos``           the servo check is over (at most 30 s)      ``arm``
``arm``              PX4 acknowledges arming, take-off altitude  ``take_off``
                     and take-off
``take_off``         90 % of the climb and PX4 in Hold           ``settle``
                     (``takeoff_timeout_s``)
``settle``           climb rate below ``settle_climb_rate_m_s``  stream the hold
                     for ``settle_s`` (at most 20 s)             setpoint: ``stream``
``stream``           ``handover_stream_s`` of it                 ask for OFFBOARD
``offboard``         PX4 acknowledges OFFBOARD                   start the mission:
                                                                 ``mission``
``mission``          the pickup's last phase, or PX4 left        ``land`` (level), or
                     OFFBOARD                                    the ``offboard_lost``
                                                                 fault
===================  ==========================================  ======================

Landing (:meth:`FlightSequence.land`, the end of every flight that did not give the
vehicle to PX4): stream the way out (level in the air, level at the thrust floor on the
ground) until PX4 acknowledges AUTO.LAND, then wait until a HEARTBEAT newer than that
acknowledgement says disarmed (``land_timeout_s``; PX4 sends them at 1 Hz, so one from
before the arming may still say disarmed).

Reactions (:meth:`FlightSequence.react`, the fault's :class:`~companion.mission.failsafe.Reaction`
set, table in :mod:`companion.mission.failsafe`): ``release_to_px4`` stops streaming and ends;
``hold_then_land`` asks PX4 for Hold (AUTO.LOITER) streaming the way out, flies 2 s in it
(a refused Hold is noted, not fatal), then lands; ``link_lost`` waits up to 60 s for the
link to return before landing; the rest land at once. Faults that end the pickup without
ending the flight (the object not carried) are the mission's
(:meth:`~companion.mission.pickup.PickupMission.abandon`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING

from companion.link.telemetry import VehicleStatus
from companion.mission.failsafe import FaultEvent, Reaction
from companion.mission.offboard import Stream

if TYPE_CHECKING:
    from companion.config import Flight

__all__ = [
    "WAIT",
    "AwaitLink",
    "CheckServos",
    "Command",
    "FlightSequence",
    "Landed",
    "Note",
    "Observation",
    "OffboardLost",
    "Px4Request",
    "Request",
    "SequenceFailed",
    "SequenceTimes",
    "Stage",
    "StartMission",
    "StreamTo",
]

SERVO_CHECK_WAIT_S = 30.0
"""Longest servo check on the ground before arming [s]
(:mod:`companion.mission.servo_check`)."""
HOLD_BEFORE_LAND_S = 2.0
"""Vehicle time flown in PX4's Hold before landing after a ``hold_then_land`` fault [s]."""
LINK_RETURN_S = 60.0
"""Longest wait for a lost link to return before the landing can be asked for [s]."""
ESTIMATE_WAIT_S = 2.0
SETTLE_WAIT_S = 20.0
MIN_CRUISE_CLEARANCE_M = 0.5


class SequenceFailed(RuntimeError):
    """The sequence cannot go on (a limit passed, a refused command); one line."""


class Stage(StrEnum):
    """Where the flight is (see the module docstring's table)."""

    IDLE = "idle"
    ESTIMATE = "estimate"
    SERVOS = "servos"
    ARM = "arm"
    TAKE_OFF = "take_off"
    SETTLE = "settle"
    STREAM = "stream"
    OFFBOARD = "offboard"
    MISSION = "mission"
    HOLD = "hold"
    HOLDING = "holding"
    LINK = "link"
    LAND = "land"
    LANDING = "landing"
    DONE = "done"


class Request(StrEnum):
    """What is asked of PX4 (and waits for its acknowledgement)."""

    ARM = "arm"
    TAKEOFF_ALTITUDE = "takeoff_altitude"
    TAKEOFF = "takeoff"
    OFFBOARD = "offboard"
    HOLD = "hold"
    LAND = "land"


_HEIGHT_STAGES = frozenset({Stage.ESTIMATE, Stage.TAKE_OFF, Stage.SETTLE})
"""The stages that decide on the estimated height and climb rate."""


@dataclass(frozen=True)
class Observation:
    """What the app sees after a control cycle.

    ``t_s`` is the vehicle time of the last cycle [s] (NaN before the first);
    ``altitude_m`` and ``climb_rate_m_s`` the estimated z and z rate (world ENU; -inf and
    inf without an estimate); ``heartbeat`` PX4's latest HEARTBEAT (each a new object);
    ``mission_done`` the pickup's last phase reached; ``left_offboard`` PX4 shows another
    mode than OFFBOARD after accepting it; ``link_lost`` the link's watchdog says lost;
    ``servos_checked`` the servo check on the ground is over.
    """

    t_s: float
    ready: bool = False
    altitude_m: float = -math.inf
    climb_rate_m_s: float = math.inf
    heartbeat: VehicleStatus | None = None
    mission_done: bool = False
    left_offboard: bool = False
    link_lost: bool = False
    servos_checked: bool = False

    @property
    def mode(self) -> str | None:
        return None if self.heartbeat is None else self.heartbeat.mode.name


@dataclass(frozen=True)
class Note:
    """An event for the log (kind, text)."""

    kind: str
    text: str


@dataclass(frozen=True)
class StreamTo:
    """Change what the control loop streams to PX4."""

    stream: Stream


@dataclass(frozen=True)
class Px4Request:
    """Ask PX4 and wait for its acknowledgement; ``value`` for the take-off altitude above
    home [m]. ``stream`` (if set) is streamed while the request waits and OFF after it."""

    request: Request
    value: float = math.nan
    stream: Stream | None = None


@dataclass(frozen=True)
class CheckServos:
    """Hold the arm at the servo check's poses on the ground (the vehicle disarmed)."""


@dataclass(frozen=True)
class StartMission:
    """PX4 acknowledged OFFBOARD: close the loop (mission, trim, stream CONTROL)."""


@dataclass(frozen=True)
class AwaitLink:
    """Stop streaming and wait until the link returns, at most ``timeout_s`` [s]."""

    timeout_s: float


@dataclass(frozen=True)
class OffboardLost:
    """PX4 left OFFBOARD while the mission flew (raise the ``offboard_lost`` fault)."""

    detail: str


@dataclass(frozen=True)
class Landed:
    """PX4 landed and disarmed after the landing was asked for."""


@dataclass(frozen=True)
class _Wait:
    """Nothing to do before the next control cycle."""


WAIT = _Wait()
Command = (
    Note
    | StreamTo
    | Px4Request
    | CheckServos
    | StartMission
    | AwaitLink
    | OffboardLost
    | Landed
    | _Wait
)


@dataclass(frozen=True)
class SequenceTimes:
    """Limits and durations of the sequence (vehicle time [s], heights [m])."""

    cruise_altitude_m: float
    settle_climb_rate_m_s: float
    settle_s: float
    handover_stream_s: float
    takeoff_timeout_s: float = 30.0
    land_timeout_s: float = 60.0
    standing_height_m: float | None = None
    """The base CoM's height above the ground when standing [m]: set, the mission's
    heights (the cruise altitude among them) are above the ground the vehicle takes off
    from; None: PX4's local Z."""

    @classmethod
    def of_flight(
        cls,
        flight: Flight,
        cruise_altitude_m: float,
        takeoff_timeout_s: float,
        land_timeout_s: float,
    ) -> SequenceTimes:
        """The limits of the config's ``[flight]`` section, the plan's cruise altitude."""
        return cls(
            cruise_altitude_m, flight.settle_climb_rate_m_s, flight.settle_s,
            flight.handover_stream_s, takeoff_timeout_s, land_timeout_s,
            flight.standing_height_m,
        )  # fmt: skip


@dataclass
class FlightSequence:
    """The flight's stages (module docstring); one instance per flight.

    ``start_from`` is given, before arming, the height the vehicle stands at and how far
    up the mission's heights move into PX4's local frame (:attr:`height_offset_m`) [m];
    it moves the plan's heights and tells why the plan cannot be flown (None: it can):
    :meth:`~companion.mission.pickup.PickupMission.start_from` with the ground margin.
    ``check_servos``: measure the servos' torque constants on the ground before arming.
    """

    times: SequenceTimes
    start_from: Callable[[float, float], str | None]
    check_servos: bool = False
    stage: Stage = Stage.IDLE
    ground_z_m: float = math.nan
    """Height of the vehicle standing on the ground, taken before arming [m]."""
    height_offset_m: float = 0.0
    """PX4's local Z of the mission's height 0 [m]: the ground under the standing vehicle
    with ``times.standing_height_m``, else 0 (the mission's heights are PX4's)."""
    _since_s: float = math.nan
    _held_since_s: float = math.nan
    _pending: list[Command] = field(default_factory=list)
    _awaited: Px4Request | AwaitLink | None = None
    _failure: SequenceFailed | None = None
    _safe: Stream = Stream.LEVEL
    _link_fault: bool = False
    _acknowledged: VehicleStatus | None = None

    # ----------------------------------------------------------------- entries

    def begin(self) -> None:
        """The pickup from the ground (the vehicle disarmed, on the ground)."""
        self._enter(Stage.ESTIMATE, math.nan)

    def land(self, stream: Stream, t_s: float) -> None:
        """Land now, streaming ``stream`` until PX4 acknowledges (whatever came before)."""
        self._pending.clear()
        self._awaited = self._failure = None
        self._safe = stream
        self._enter(Stage.LAND, t_s)

    def react(self, event: FaultEvent, link_fault: bool, t_s: float) -> None:
        """Carry out an aborting fault's reactions (the pickup has stopped); ``link_fault``:
        the fault is the lost link."""
        self._pending.clear()
        self._awaited = self._failure = None
        self._link_fault = link_fault
        if Reaction.RELEASE_TO_PX4 in event.reactions:
            self._pending.append(StreamTo(Stream.OFF))
            self._enter(Stage.DONE, t_s)
            return
        ground = Reaction.LEVEL_ON_GROUND in event.reactions
        self._safe = Stream.GROUND if ground else Stream.LEVEL
        hold = Reaction.HOLD_THEN_LAND in event.reactions
        self._enter(Stage.HOLD if hold else Stage.LINK, t_s)

    @property
    def watches_height(self) -> bool:
        """Whether the stage decides on the estimated height or climb rate (an
        :class:`Observation` without them reads -inf and inf)."""
        return self.stage in _HEIGHT_STAGES

    @property
    def finished(self) -> bool:
        """Nothing more to do: landed and disarmed, or the vehicle given to PX4."""
        return self.stage == Stage.DONE and not self._pending

    # ------------------------------------------------------------------ events

    def done(self, obs: Observation, error: str | None = None) -> None:
        """The awaited :class:`Px4Request` or :class:`AwaitLink` ended; ``error``: PX4
        refused (its words) or the wait timed out."""
        awaited, self._awaited = self._awaited, None
        if awaited is None:
            raise RuntimeError("nothing was awaited")
        stage = self.stage
        if stage == Stage.ARM:
            assert isinstance(awaited, Px4Request)
            self._arming(awaited.request, obs, error)
        elif stage == Stage.OFFBOARD:
            if error is not None:
                self._pending.append(StreamTo(Stream.OFF))
                self._fail(f"PX4 refused OFFBOARD: {error}")
                return
            self._pending.append(StartMission())
            self._pending.append(
                Note("mode", "OFFBOARD accepted: the control loop flies the vehicle")
            )
            self._enter(Stage.MISSION, obs.t_s)
        elif stage == Stage.HOLD:
            if error is not None:
                self._pending.append(Note("fault", f"PX4 refused to hold: {error}"))
                self._enter(Stage.LINK, obs.t_s)
            else:
                self._enter(Stage.HOLDING, obs.t_s)
        elif stage == Stage.LINK:
            if error is not None:
                self._fail(f"the MAVLink link did not return within {LINK_RETURN_S:g} s")
                return
            self._pending.append(Note("link", "regained"))
            self._enter(Stage.LAND, obs.t_s)
        elif stage == Stage.LAND:
            if error is not None:
                self._fail(f"PX4 refused to land: {error}")
                return
            self._pending.append(Note("mode", "landing"))
            self._acknowledged = obs.heartbeat
            self._enter(Stage.LANDING, obs.t_s)

    def next(self, obs: Observation) -> Command:
        """The next command after observing ``obs``; :data:`WAIT` until the next cycle.
        Raises :class:`SequenceFailed` once the commands before the failure are out."""
        if self._pending:
            command = self._pending.pop(0)
            if isinstance(command, Px4Request | AwaitLink):
                self._awaited = command
            return command
        if self._failure is not None:
            raise self._failure
        if self._awaited is not None:
            raise RuntimeError(f"{self._awaited} is still waiting for its end")
        if not self._advance(obs):
            return WAIT
        return self.next(obs)

    # ------------------------------------------------------------------ stages

    def _advance(self, obs: Observation) -> bool:
        """Check the stage's condition at ``obs``; whether anything changed."""
        stage = self.stage
        if math.isnan(self._since_s):
            self._since_s = obs.t_s  # entered before the first control cycle
        if stage == Stage.ESTIMATE:
            if not obs.ready:
                return self._limit(obs, ESTIMATE_WAIT_S, "no state estimate")
            self._leave_ground(obs)
        elif stage == Stage.SERVOS:
            if not obs.servos_checked:
                return self._limit(obs, SERVO_CHECK_WAIT_S, "the servo check did not end")
            self._arm(obs)
        elif stage == Stage.TAKE_OFF:
            climbed = obs.altitude_m - self.ground_z_m >= 0.9 * self._climb_m()
            if not (climbed and obs.mode == "LOITER"):
                limit_s = self.times.takeoff_timeout_s
                return self._limit(obs, limit_s, "take-off did not reach the cruise altitude")
            self._enter(Stage.SETTLE, obs.t_s)
        elif stage == Stage.SETTLE:
            if not self._held(obs, abs(obs.climb_rate_m_s) < self.times.settle_climb_rate_m_s):
                what = "the vehicle did not stop climbing after take-off"
                return self._limit(obs, SETTLE_WAIT_S, what)
            self._pending.append(StreamTo(Stream.HOLD))
            self._enter(Stage.STREAM, obs.t_s)
        elif stage == Stage.STREAM:
            if obs.t_s - self._since_s < self.times.handover_stream_s:
                return False
            self._enter(Stage.OFFBOARD, obs.t_s)
            self._pending.append(Px4Request(Request.OFFBOARD))
        elif stage == Stage.MISSION:
            if obs.mission_done:
                self.land(Stream.LEVEL, obs.t_s)
            elif obs.left_offboard:
                self._pending.append(OffboardLost(f"PX4 left OFFBOARD (now {obs.mode})"))
                self._enter(Stage.DONE, obs.t_s)
            else:
                return False
        elif stage == Stage.HOLD:
            self._pending.append(Px4Request(Request.HOLD, stream=self._safe))
        elif stage == Stage.HOLDING:
            if obs.t_s - self._since_s < HOLD_BEFORE_LAND_S:
                return False
            self._enter(Stage.LINK, obs.t_s)
        elif stage == Stage.LINK:
            if self._link_fault and obs.link_lost:
                self._link_fault = False
                self._pending += [StreamTo(Stream.OFF), AwaitLink(LINK_RETURN_S)]
            else:
                self._enter(Stage.LAND, obs.t_s)
        elif stage == Stage.LAND:
            self._pending.append(Px4Request(Request.LAND, stream=self._safe))
        elif stage == Stage.LANDING:
            status = obs.heartbeat
            if status is None or status is self._acknowledged or status.armed:
                limit_s = self.times.land_timeout_s
                return self._limit(obs, limit_s, "the vehicle did not land and disarm")
            self._pending += [Landed(), Note("mode", "disarmed")]
            self._enter(Stage.DONE, obs.t_s)
        else:
            return False
        return True

    def _leave_ground(self, obs: Observation) -> None:
        self.ground_z_m = obs.altitude_m
        standing = self.times.standing_height_m
        if standing is not None:
            self.height_offset_m = self.ground_z_m - standing
            where = (
                f"heights above the ground, which lies at z = {self.height_offset_m:.2f} m "
                f"in PX4's local frame ({standing:g} m below the standing vehicle)"
            )
        else:
            where = "heights are PX4's local Z ([flight] standing_height_m is not set)"
        self._pending.append(Note("preflight", where))
        cruise = self._cruise_m()
        if cruise - self.ground_z_m < MIN_CRUISE_CLEARANCE_M:
            self._fail(
                f"the cruise altitude {self.times.cruise_altitude_m:g} m is less than "
                f"{MIN_CRUISE_CLEARANCE_M:g} m above where the vehicle stands (z = "
                f"{self.ground_z_m:.2f} m in PX4's local frame, the cruise at {cruise:.2f} m)"
            )
            return
        unreachable = self.start_from(self.ground_z_m, self.height_offset_m)
        if unreachable is not None:
            self._fail(unreachable)
            return
        if self.check_servos:
            self._pending.append(CheckServos())
            self._enter(Stage.SERVOS, obs.t_s)
            return
        self._arm(obs)

    def _arm(self, obs: Observation) -> None:
        self._pending.append(Note("mode", f"arming (standing at z = {self.ground_z_m:.2f} m)"))
        self._pending.append(Px4Request(Request.ARM))
        self._enter(Stage.ARM, obs.t_s)

    def _arming(self, request: Request, obs: Observation, error: str | None) -> None:
        """Arm, set the take-off altitude, take off: one refusal is the take-off's."""
        if error is not None:
            self._fail(f"take-off refused: {error}")
        elif request == Request.ARM:
            self._pending.append(Px4Request(Request.TAKEOFF_ALTITUDE, self._climb_m()))
        elif request == Request.TAKEOFF_ALTITUDE:
            self._pending.append(Px4Request(Request.TAKEOFF))
        else:
            self._pending.append(Note("mode", "take-off"))
            self._enter(Stage.TAKE_OFF, obs.t_s)

    def _cruise_m(self) -> float:
        """The cruise altitude in PX4's local frame [m]."""
        return self.times.cruise_altitude_m + self.height_offset_m

    def _climb_m(self) -> float:
        """The take-off's climb: MIS_TAKEOFF_ALT is above home (where PX4 armed), the cruise
        altitude is in the local frame, whose origin need not be on the ground [m]."""
        return self._cruise_m() - self.ground_z_m

    def _enter(self, stage: Stage, t_s: float) -> None:
        self.stage = stage
        self._since_s = t_s
        self._held_since_s = math.nan

    def _fail(self, message: str) -> None:
        self._failure = SequenceFailed(message)

    def _held(self, obs: Observation, condition: bool) -> bool:
        """``condition`` has held for ``settle_s`` of vehicle time."""
        if not condition:
            self._held_since_s = math.nan
            return False
        if math.isnan(self._held_since_s):
            self._held_since_s = obs.t_s
        return obs.t_s - self._held_since_s >= self.times.settle_s

    def _limit(self, obs: Observation, limit_s: float, what: str) -> bool:
        """Fail once the stage has waited more than ``limit_s``; whether it failed."""
        if obs.t_s - self._since_s > limit_s:
            self._fail(f"{what} within {limit_s:g} s")
            return True
        return False

"""The payload-pickup mission as a pure state machine over vehicle time.

PX4 takes off and lands (AUTO.TAKEOFF, AUTO.LAND); between the two the companion flies in
OFFBOARD and this planner gives it, every control cycle, the desired state q_d (with
q_d_dot, q_d_ddot) in world ENU and joint angles, the gripper command and what the
estimator should do. Phases, in order:

``to_object``   fly at cruise altitude to above the object, arm lowered (straight down)
``descend``     lower until the jaws' grasp point on link 2 meets the object
``grasp``       close the gripper, wait ``grasp_wait_s``; the estimator restarts its confidence
``lift``        climb back to cruise altitude with the payload; the estimator restarts as it
                begins and once more :data:`LIFT_RESTART_M` up
``excite``      swing the arm and circle until the estimator is confident (or time out),
                fade out, and hold until the vehicle is back within ``arrive_tolerance_m``
``to_place``    carry to above the place point
``lower``       lower until the grasp point is at the place point
``release``     open the gripper, wait; the estimator restarts as the gripper opens and
                learns the weight leaving, then returns to the empty-arm values
``climb``       climb to cruise altitude
``to_home``     fly back above the start point, arm stowed; then the app asks PX4 to land

When the object is not in the gripper (:mod:`companion.mission.carry_check` decides, the app calls
:meth:`PickupMission.abandon`), the pickup stops where it is and ends with

``return``      climb straight up to cruise altitude (at least ``return_hold_s``, holding
                position), arm down, the estimator back at the empty arm and held;
                then ``to_home`` and the landing, with the :class:`Outcome` the reason
                (``grasp_failed``: the gripper is opened, whatever it touches is let go;
                ``payload_lost``: it stays as it is; ``beyond_authority``, a payload the
                vehicle or the servos cannot carry (:mod:`companion.mission.authority`),
                checked from the end of the grasp through the lift's first centimetres:
                opened, as for a failed grasp, so the object stays where it lay). The
                mission never ends
                ``completed`` without having carried the object to the place point.

Every move is a minimum-jerk (quintic) segment, so q_d_dot and q_d_ddot are continuous and
at rest at both ends; a phase ends when its segment is over and the vehicle is within
``arrive_tolerance_m`` of its end point (the tracking error is part of the mission, not
hidden by a timer); ``descend`` and ``lower`` end only once the error has stayed within
``grasp_tolerance_m`` for ``settle_s``, so the jaws close on the object, not beside it.
A phase that never arrives ends after ``arrive_timeout_s`` more. The estimator runs from
the grasp on (and after the release, to show the estimate return to the empty arm).
Geometry: with the arm straight down (eta1 = -pi/2, eta2 = 0) the
grasp point lies ``mount_z + l1 + grasp_point`` below the base CoM (DESIGN.md
section 3), so the base flies that much above the object. The companion does not know the
payload: the grasp point is where its own jaws close (``PickupPlan.grasp_point_m``).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from companion.config import CompanionConfig
from companion.control.laws import DesiredState
from companion.coordinates import ETA1, ETA2, HORIZONTAL, JOINTS, N_Q, POSITION, PSI, TILT, X, Y, Z

__all__ = [
    "LETS_GO",
    "LIFT_RESTART_M",
    "PICKUP_ORDER",
    "WEIGH_HEIGHT_M",
    "EstimatorAction",
    "GripperAction",
    "MissionCommand",
    "Outcome",
    "Phase",
    "PickupMission",
    "PickupPlan",
    "min_jerk",
]

FloatArray = NDArray[np.float64]
ARM_DOWN = (-0.5 * math.pi, 0.0)
"""(eta1, eta2) with the arm straight down [rad]."""


class Phase(StrEnum):
    """Mission phases flown in OFFBOARD, in order."""

    TO_OBJECT = "to_object"
    DESCEND = "descend"
    GRASP = "grasp"
    LIFT = "lift"
    EXCITE = "excite"
    TO_PLACE = "to_place"
    LOWER = "lower"
    RELEASE = "release"
    CLIMB = "climb"
    TO_HOME = "to_home"
    DONE = "done"
    RETURN = "return"
    """Out of order: after :meth:`PickupMission.abandon`, then ``to_home``."""


PICKUP_ORDER = tuple(p for p in Phase if p != Phase.RETURN)
"""The phases of a pickup that carried its object, in order."""
_NEXT: dict[Phase, Phase] = {
    **dict(itertools.pairwise(PICKUP_ORDER)),
    Phase.RETURN: Phase.TO_HOME,
}


class Outcome(StrEnum):
    """How the mission ended (the summary's ``outcome``)."""

    COMPLETED = "completed"
    """The object was carried to the place point and released there."""
    GRASP_FAILED = "grasp_failed"
    """The gripper closed on nothing: nothing carried; returned home."""
    PAYLOAD_LOST = "payload_lost"
    """The object left the gripper before the place point: carry stopped; returned home."""
    BEYOND_AUTHORITY = "beyond_authority"
    """The payload needs more thrust or servo torque than the vehicle may give
    (:mod:`companion.mission.authority`): let go where it was grasped; returned home."""


LETS_GO: frozenset[Outcome] = frozenset({Outcome.GRASP_FAILED, Outcome.BEYOND_AUTHORITY})
"""The outcomes of :meth:`PickupMission.abandon` that open the gripper (whatever it touches
is let go where it is); ``payload_lost`` leaves it as it is."""


_FROZEN_PHASES = frozenset({Phase.DONE})
"""The estimator holds still after the mission; after an
:meth:`PickupMission.abandon` it holds the empty arm's values to the end. It runs from
the start of the grasp (restarted there): an object whose weight comes onto the arm as
the jaws close is learnt at once, not after a dip of its weight over the height gain (10
cm for 0.4 kg, measured when the SITL attached it at the jaws' closing: the vehicle
reached the ground-contact height); an object still on the ground (as in the SITL now)
only gives the empty arm's data until it lifts, so the estimator restarts again as the
lift begins (the weight comes over while the vehicle has yet to rise: with the grasp's
covariance the default pickup sank 5.4 cm below the lift's reference, 4.2 cm with this
restart, 0.42 kg 9.3 and 7.6 cm) and once more when the lift has gained
:data:`LIFT_RESTART_M`. The release mirrors the grasp: the estimator restarts as the
gripper opens and runs through the release's wait, so it learns the weight as it leaves
(held at the payload's values there, the default pickup rose 7.3 cm over the place
point); what it does not see leave, it keeps (set to the empty arm as the gripper opened,
a PX4 SIH vehicle whose estimate held 0.185 kg it did not carry sank into the ground)."""
_CALIBRATION_PHASES = frozenset({Phase.TO_OBJECT, Phase.DESCEND})
"""Until the grasp the arm is known empty: the estimator holds the empty-arm values and
learns only the thrust scale (:attr:`EstimatorAction.CALIBRATE`)."""


WEIGH_HEIGHT_M = 0.1
"""The lift's first metres, above where it began, in which the payload is checked
(:mod:`companion.mission.authority`, :meth:`PickupMission.weighing`) [m]: the most it can
fall when let go there."""
LIFT_RESTART_M = 0.05
"""Height the lift has gained [m] when the estimator restarts once more
(:attr:`EstimatorAction.RESTART`): an object standing on the ground gives its weight to
the arm only as it leaves the ground, and by then it has; the empty arm's seconds of the
grasp would otherwise have narrowed the covariance the weight is learnt with (the RLS
then follows it with its forgetting's time constant, about 8 s)."""


class GripperAction(StrEnum):
    """What the gripper should do this cycle."""

    HOLD = "hold"
    OPEN = "open"
    CLOSE = "close"


class EstimatorAction(StrEnum):
    """What the estimator should do this cycle."""

    RUN = "run"
    FREEZE = "freeze"
    CALIBRATE = "calibrate"
    """Hold theta at the empty arm's values and learn the thrust scale alone (a hover
    calibration; the estimator holds both where it has no thrust scale)."""
    RESTART = "restart"
    """Keep theta, restart its covariance and confidence, hold the thrust scale: the
    grasp begins, the lift begins, the lift has gained :data:`LIFT_RESTART_M`, and the
    release begins."""
    RESET_EMPTY = "reset_empty"
    """Back to the empty-arm values: the payload was just released (at the release's end;
    reset as the gripper opens, the SITL's default pickup no longer rose 7 cm over the
    place point, but with PX4 SIH, the estimate unconfident at 0.185 kg, the vehicle sank
    into ``ground_contact`` 0.3 s after the reset, low over the point)."""
    EMPTY = "empty"
    """Back to the empty-arm values and held there for the rest of the flight: the object
    was lost or never grasped, the arm is known to be empty (as before the grasp), and the
    cycles after the loss carry its transient (measured in the SITL's slip: estimating on
    from the reset, m2 went to its lower bound in the first cycle, then to twice the empty
    value)."""


@dataclass(frozen=True)
class PickupPlan:
    """Where and how to fly the pickup (world ENU [m], [m/s], [s], [rad]).

    ``payload_at`` and ``place_at`` are where the object's centre of mass is and should
    end up.
    """

    home_m: tuple[float, float]
    payload_at_m: tuple[float, float, float]
    place_at_m: tuple[float, float, float]
    yaw_rad: float | None = None
    """Heading flown [rad, ENU]; None: the heading the vehicle has when the mission starts
    (no turn at the OFFBOARD handover)."""
    stow_joints_rad: tuple[float, float] = (0.0, -0.5 * math.pi)
    grasp_point_m: float | None = None
    """Where along link 2 the closed jaws hold an object, from joint 2 [m]; default 2 cm
    inside the tip (l2 - 0.02)."""
    cruise_altitude_m: float = 1.5
    cruise_speed_m_s: float = 0.5
    vertical_speed_m_s: float = 0.3
    arm_move_s: float = 3.0
    grasp_wait_s: float = 1.5
    excite_min_s: float = 6.0
    excite_max_s: float = 30.0
    excite_period_s: float = 4.0
    excite_eta1_rad: float = 0.5
    excite_eta2_rad: float = 0.4
    excite_radius_m: float = 0.15
    excite_payload_kg: float | None = None
    """The payload the joints' swing amplitudes are for [kg]: a heavier payload (its
    estimate as the excitation begins) swings them by the square root of this over its
    mass; None: the full amplitudes for every payload."""
    arrive_tolerance_m: float = 0.15
    arrive_timeout_s: float = 20.0
    grasp_tolerance_m: float = 0.03
    """Tracking error within which the jaws may close on (or open over) a point [m]."""
    settle_s: float = 0.5
    """Time the error must stay within ``grasp_tolerance_m`` before grasping or placing [s]."""
    return_hold_s: float = 2.0
    """Shortest ``return`` phase [s]: the vehicle holds (or climbs) while the estimator,
    back at the empty arm, settles."""

    def raised(self, dz_m: float) -> PickupPlan:
        """The plan with every height (the points' Z, the cruise altitude) ``dz_m`` [m]
        higher: from heights above the ground to PX4's local frame."""
        obj, place = self.payload_at_m, self.place_at_m
        return replace(
            self,
            payload_at_m=(obj[0], obj[1], obj[2] + dz_m),
            place_at_m=(place[0], place[1], place[2] + dz_m),
            cruise_altitude_m=self.cruise_altitude_m + dz_m,
        )

    def __post_init__(self) -> None:
        values = [*self.home_m, *self.payload_at_m, *self.place_at_m]
        values += [] if self.yaw_rad is None else [self.yaw_rad]
        values += list(self.stow_joints_rad)
        if not all(math.isfinite(v) for v in values):
            raise ValueError("mission positions must be finite")
        positive = ("cruise_speed_m_s", "vertical_speed_m_s", "arm_move_s", "excite_period_s")
        for name in (*positive, "return_hold_s"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be positive")
        if self.excite_payload_kg is not None and not self.excite_payload_kg > 0.0:
            raise ValueError("excite_payload_kg must be positive")
        if not self.excite_max_s >= self.excite_min_s + self.excite_period_s:
            raise ValueError("need excite_max_s >= excite_min_s + excite_period_s")


def min_jerk(
    t_s: float,
    duration_s: float,
    start: FloatArray,
    end: FloatArray,
    start_velocity: FloatArray | None = None,
):
    """Quintic from ``start`` to ``end`` over ``duration_s``, at rest at the end and with
    zero acceleration at both ends; it leaves ``start`` at ``start_velocity`` (default at
    rest: then it is the minimum-jerk move).

    With D = end - start, v0 = start_velocity and T = duration: ``q = start + v0 t
    + (10 D - 6 v0 T) t^3/T^3 + (-15 D + 8 v0 T) t^4/T^4 + (6 D - 3 v0 T) t^5/T^5``.
    Returns (position, velocity, acceleration) at ``t_s`` (clamped to [0, duration]).
    """
    big_t = duration_s
    tau = min(max(t_s / big_t, 0.0), 1.0)
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau * tau)
    ds = 30.0 * tau**2 * (1.0 - tau) ** 2 / big_t
    dds = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau) / big_t**2
    delta = end - start
    q, q_dot, q_ddot = start + s * delta, ds * delta, dds * delta
    if start_velocity is None:
        return q, q_dot, q_ddot
    # The v0 part: v0 T (tau - 6 tau^3 + 8 tau^4 - 3 tau^5), zero at both ends with zero
    # slope at the end and zero curvature at both.
    v0 = np.asarray(start_velocity, dtype=np.float64)
    g = tau - 6.0 * tau**3 + 8.0 * tau**4 - 3.0 * tau**5
    dg = (1.0 - 18.0 * tau**2 + 32.0 * tau**3 - 15.0 * tau**4) / big_t
    ddg = (-36.0 * tau + 96.0 * tau**2 - 60.0 * tau**3) / big_t**2
    return q + v0 * big_t * g, q_dot + v0 * big_t * dg, q_ddot + v0 * big_t * ddg


@dataclass(frozen=True)
class MissionCommand:
    """The planner's output for one control cycle."""

    phase: Phase
    desired: DesiredState
    """q_d, q_d_dot, q_d_ddot, shape (8,) each (roll and pitch rows are replaced by the
    controller's tilt reference)."""
    gripper: GripperAction
    estimator: EstimatorAction
    phase_changed: bool


@dataclass
class _Segment:
    start_s: float
    duration_s: float
    q_from: FloatArray
    q_to: FloatArray
    check_arrival: bool = True
    v_from: FloatArray | None = None
    """Velocity the segment starts with (the handover's), None: at rest."""


@dataclass
class PickupMission:
    """The OFFBOARD part of the pickup; see the module docstring.

    Parameters
    ----------
    plan
        Mission geometry and timing.
    scenario
        Arm geometry (mount point, l1, payload position along link 2).
    """

    plan: PickupPlan
    scenario: CompanionConfig
    phase: Phase = Phase.TO_OBJECT
    confident_when_done: bool = False
    phase_log: list[tuple[float, Phase]] = field(default_factory=list)
    outcome: Outcome = Outcome.COMPLETED
    """How the mission ends (final once ``phase`` is DONE)."""
    outcome_detail: str = ""
    """Why, for an outcome other than ``completed``."""
    _segment: _Segment | None = None
    _excite_stop_s: float = math.nan
    _settled_since: float = math.nan
    _lift_restarted: bool = False
    _swing: float = 1.0
    _yaw_rad: float = 0.0
    _return_xy_m: tuple[float, float] = (0.0, 0.0)

    @property
    def grasp_point_m(self) -> float:
        """Where along link 2 the closed jaws hold the object, from joint 2 [m]."""
        grasp = self.plan.grasp_point_m
        return self.scenario.arm.link2.length_m - 0.02 if grasp is None else grasp

    @property
    def hang_m(self) -> float:
        """Height of the base CoM above the jaws' grasp point with the arm down [m]."""
        arm = self.scenario.arm
        return -arm.mount_point_m[2] + arm.link1.length_m + self.grasp_point_m

    def loaded_poses(self, payload_kg: float = 0.0) -> tuple[tuple[float, float], ...]:
        """The (eta1, eta2) [rad] the arm takes with a payload of ``payload_kg`` [kg]:
        straight down, and the excitation's two extremes (its joints swing in phase, by
        :meth:`swing_scale` of the plan's amplitudes)."""
        down1, down2 = ARM_DOWN
        swing = self.swing_scale(payload_kg)
        a1, a2 = self.plan.excite_eta1_rad * swing, self.plan.excite_eta2_rad * swing
        return (ARM_DOWN, (down1 + a1, down2 + a2), (down1 - a1, down2 - a2))

    def start_from(self, ground_z_m: float, height_offset_m: float, margin_m: float) -> str | None:
        """Before take-off, from the vehicle standing at ``ground_z_m``: move the plan's
        heights ``height_offset_m`` up into PX4's local frame (:meth:`PickupPlan.raised`;
        0 when they are PX4's already) and tell why it cannot be flown (:meth:`unreachable`)
        [m]. RuntimeError once the mission flies."""
        if self._segment is not None or self.phase_log:
            raise RuntimeError("the plan's heights are set before the mission flies")
        self.plan = self.plan.raised(height_offset_m)
        return self.unreachable(ground_z_m, margin_m)

    def unreachable(self, ground_z_m: float, margin_m: float) -> str | None:
        """Why the object or the place point cannot be reached from a vehicle standing at
        ``ground_z_m`` [m, local frame], or None: the grasp and the release hover the
        base's CoM :attr:`hang_m` above the point, which must stay ``margin_m`` above
        where the vehicle stands (the ground_contact fault's height). The points are in
        PX4's local frame, whose origin need not be on the ground (with GPS, EKF2's
        origin is the standing vehicle), so only the vehicle can tell."""
        floor = ground_z_m + margin_m
        for name, point in (
            ("object", self.plan.payload_at_m),
            ("place point", self.plan.place_at_m),
        ):
            hover = point[2] + self.hang_m
            if hover < floor:
                return (
                    f"the {name} at z = {point[2]:.2f} m is out of the arm's reach: the vehicle "
                    f"would hover at z = {hover:.2f} m, below where it stands "
                    f"(z = {ground_z_m:.2f} m in PX4's local frame) + the {margin_m:g} m "
                    "ground margin"
                )
        return None

    def _pose(self, xyz: tuple[float, float, float] | FloatArray, eta) -> FloatArray:
        return np.array([xyz[0], xyz[1], xyz[2], 0.0, 0.0, self._yaw_rad, eta[0], eta[1]])

    def _targets(self, phase: Phase) -> FloatArray:
        p = self.plan
        cruise = p.cruise_altitude_m
        obj, place = p.payload_at_m, p.place_at_m
        hang = self.hang_m
        return {
            Phase.TO_OBJECT: self._pose((obj[0], obj[1], cruise), ARM_DOWN),
            Phase.DESCEND: self._pose((obj[0], obj[1], obj[2] + hang), ARM_DOWN),
            Phase.GRASP: self._pose((obj[0], obj[1], obj[2] + hang), ARM_DOWN),
            Phase.LIFT: self._pose((obj[0], obj[1], cruise), ARM_DOWN),
            Phase.EXCITE: self._pose((obj[0], obj[1], cruise), ARM_DOWN),
            Phase.TO_PLACE: self._pose((place[0], place[1], cruise), ARM_DOWN),
            Phase.LOWER: self._pose((place[0], place[1], place[2] + hang), ARM_DOWN),
            Phase.RELEASE: self._pose((place[0], place[1], place[2] + hang), ARM_DOWN),
            Phase.CLIMB: self._pose((place[0], place[1], cruise), ARM_DOWN),
            Phase.TO_HOME: self._pose((p.home_m[0], p.home_m[1], cruise), p.stow_joints_rad),
            Phase.RETURN: self._pose((*self._return_xy_m, cruise), ARM_DOWN),
        }[phase]

    def start(self, t_s: float, q_now: FloatArray, q_dot_now: FloatArray | None = None) -> None:
        """Begin at vehicle time ``t_s`` [s] from the current configuration ``q_now``, moving
        at the vehicle's current velocity ``q_dot_now`` (x, y, z rows used; default at
        rest), so the first move continues the motion PX4 handed over instead of braking
        it at once."""
        yaw = self.plan.yaw_rad
        self._yaw_rad = float(q_now[PSI]) if yaw is None else yaw
        self.phase = Phase.TO_OBJECT
        self.phase_log = [(t_s, self.phase)]
        self._begin(t_s, np.asarray(q_now, dtype=np.float64), Phase.TO_OBJECT)
        if q_dot_now is not None:
            assert self._segment is not None
            v = np.zeros(N_Q)
            v[POSITION] = np.asarray(q_dot_now, dtype=np.float64)[POSITION]
            self._segment.v_from = v

    def _begin(self, t_s: float, q_from: FloatArray, phase: Phase) -> None:
        p = self.plan
        self._settled_since = math.nan  # each phase settles on its own
        q_from = q_from.copy()
        q_from[TILT] = 0.0
        q_from[PSI] = self._yaw_rad
        q_to = self._targets(phase)
        horizontal = float(np.linalg.norm(q_to[HORIZONTAL] - q_from[HORIZONTAL]))
        vertical = abs(float(q_to[Z] - q_from[Z]))
        joints = float(np.max(np.abs(q_to[JOINTS] - q_from[JOINTS])))
        # Minimum-jerk peak speed is 1.875 x the mean speed.
        duration = max(
            1.875 * horizontal / p.cruise_speed_m_s,
            1.875 * vertical / p.vertical_speed_m_s,
            p.arm_move_s * joints / (0.5 * math.pi),
            1.0,
        )
        if phase in (Phase.GRASP, Phase.RELEASE):
            duration = p.grasp_wait_s
        if phase == Phase.RETURN:
            duration = max(duration, p.return_hold_s)
        if phase == Phase.EXCITE:
            duration = p.excite_max_s
            self._excite_stop_s = math.nan
        self._segment = _Segment(
            t_s, duration, q_from, q_to, check_arrival=phase not in (Phase.GRASP, Phase.RELEASE)
        )

    def update(
        self, t_s: float, q: FloatArray, confident: bool, payload_kg: float = 0.0
    ) -> MissionCommand:
        """Desired state, gripper and estimator actions at vehicle time ``t_s`` [s].

        ``q`` is the filtered configuration, ``confident`` the estimator's confidence flag,
        ``payload_kg`` the estimated payload (m2 over the empty link 2's) [kg], which sets
        the excitation's swing as it begins (:meth:`swing_scale`).
        """
        if self._segment is None:
            raise RuntimeError("call start() before update()")
        changed = False
        gripper, estimator = GripperAction.HOLD, EstimatorAction.RUN
        if self.phase != Phase.DONE and self._finished(t_s, q, confident):
            q_end = self._desired(t_s).q
            finished = self.phase
            self.phase = _NEXT[self.phase]
            self.phase_log.append((t_s, self.phase))
            changed = True
            if finished in (Phase.DESCEND, Phase.GRASP, Phase.LOWER):
                estimator = EstimatorAction.RESTART
            if finished == Phase.RELEASE:
                estimator = EstimatorAction.RESET_EMPTY
            if self.phase == Phase.EXCITE:
                self._swing = self.swing_scale(payload_kg)
            if self.phase != Phase.DONE:
                self._begin(t_s, q_end, self.phase)
        if self.phase == Phase.LIFT and not self._lift_restarted:
            if self._lift_gain_m(float(q[Z])) >= LIFT_RESTART_M:
                self._lift_restarted = True
                estimator = EstimatorAction.RESTART
        if changed and self.phase == Phase.GRASP:
            gripper = GripperAction.CLOSE
        if changed and self.phase == Phase.RELEASE:
            gripper = GripperAction.OPEN
        abandoned = self.outcome != Outcome.COMPLETED
        if estimator == EstimatorAction.RUN:
            if self.phase in _FROZEN_PHASES or abandoned:
                estimator = EstimatorAction.FREEZE
            elif self.phase in _CALIBRATION_PHASES:
                estimator = EstimatorAction.CALIBRATE
        return MissionCommand(self.phase, self._desired(t_s), gripper, estimator, changed)

    def swing_scale(self, payload_kg: float) -> float:
        """The fraction of the plan's joint amplitudes the excitation swings with a payload
        of ``payload_kg`` [kg]: the square root of ``excite_payload_kg`` over it, at most 1.

        The moment of the payload's weight across the swing, which pushes the vehicle off
        its circle, grows with the payload times the amplitude; the estimator's excitation
        falls faster than the amplitude. Measured in the SITL (0.44 kg at 0.166 m; 0.38 kg
        at 0.116 m): full swing 36 cm RMS off the circle, CoM +1.0 % / -2.1 %; scaled by
        the mass ratio 10 cm, but the 0.38 kg never confident (excitation 1e-4 against
        3e-4) and, over the 30 s the swing then lasted, the CoM drifted to -6.7 % with the
        battery's sag; by about its square root 23 cm, +1.1 % / -2.4 %, confident in 10 s.
        """
        reference = self.plan.excite_payload_kg
        if reference is None or not payload_kg > reference:
            return 1.0
        return math.sqrt(reference / payload_kg)

    def weighing(self, z_m: float) -> bool:
        """Whether the lift, the base at height ``z_m`` [m], is within its first
        :data:`WEIGH_HEIGHT_M`: where the payload is checked against the vehicle's and the
        servos' authority."""
        return self.phase == Phase.LIFT and self._lift_gain_m(z_m) <= WEIGH_HEIGHT_M

    def _lift_gain_m(self, z_m: float) -> float:
        """Height gained above where the lift began (the grasp's height) [m]."""
        assert self._segment is not None
        return z_m - float(self._segment.q_from[Z])

    def abandon(self, t_s: float, outcome: Outcome, detail: str) -> MissionCommand:
        """Stop the pickup at vehicle time ``t_s`` [s] because the object is not carried
        (``outcome`` ``grasp_failed``, ``payload_lost`` or ``beyond_authority``, ``detail``
        why; the gripper opens for the first and the last): from where the
        desired state is now, climb straight up to cruise altitude (``return``), then home;
        returns this cycle's command (the estimator back at the empty arm, held there for
        the rest of the flight: :attr:`EstimatorAction.EMPTY`). Once only: a
        mission already returning, going home or done is left as it is."""
        if outcome == Outcome.COMPLETED:
            raise ValueError("abandon() needs the reason the object is not carried")
        if self._segment is None:
            raise RuntimeError("call start() before abandon()")
        if self.phase in (Phase.RETURN, Phase.TO_HOME, Phase.DONE):
            return MissionCommand(
                self.phase, self._desired(t_s), GripperAction.HOLD, EstimatorAction.RUN, False
            )
        now = self._desired(t_s)
        q_from = now.q
        self.outcome, self.outcome_detail = outcome, detail
        self.phase = Phase.RETURN
        self.phase_log.append((t_s, self.phase))
        self._return_xy_m = (float(q_from[X]), float(q_from[Y]))
        self._begin(t_s, q_from, Phase.RETURN)
        assert self._segment is not None
        v_from = now.q_dot.copy()  # leave the move it was in (a carry, the swing) smoothly
        v_from[TILT] = 0.0
        v_from[PSI] = 0.0
        self._segment.v_from = v_from
        gripper = GripperAction.OPEN if outcome in LETS_GO else GripperAction.HOLD
        return MissionCommand(self.phase, self._desired(t_s), gripper, EstimatorAction.EMPTY, True)

    def _finished(self, t_s: float, q: FloatArray, confident: bool) -> bool:
        seg = self._segment
        assert seg is not None
        elapsed = t_s - seg.start_s
        if self.phase == Phase.EXCITE:
            period = self.plan.excite_period_s
            if not math.isfinite(self._excite_stop_s):
                enough = confident and elapsed >= self.plan.excite_min_s
                if enough or elapsed >= seg.duration_s - period:
                    self._excite_stop_s = t_s
                    self.confident_when_done = confident
                return False
            waited = t_s - (self._excite_stop_s + period)
            if waited < 0.0:
                return False
            # The swing can push the vehicle far off its centre (a 0.4 kg payload's reaction
            # against PX4's attitude loop: up to 1.1 m in the SITL, swinging through the
            # centre): the carry starts once it has stayed back for settle_s.
            if waited >= self.plan.arrive_timeout_s:
                return True
            error = float(np.linalg.norm(q[POSITION] - seg.q_to[POSITION]))
            return self._settled(t_s, error, self.plan.arrive_tolerance_m)
        if elapsed < seg.duration_s:
            return False
        if not seg.check_arrival:
            return True
        error = float(np.linalg.norm(q[POSITION] - seg.q_to[POSITION]))
        if elapsed >= seg.duration_s + self.plan.arrive_timeout_s:
            return True
        if self.phase not in (Phase.DESCEND, Phase.LOWER):
            return error <= self.plan.arrive_tolerance_m
        # Grasping and placing need the jaws on the point, steadily.
        return self._settled(t_s, error, self.plan.grasp_tolerance_m)

    def _settled(self, t_s: float, error_m: float, tolerance_m: float) -> bool:
        """True once the position error has stayed within ``tolerance_m`` for ``settle_s``."""
        if error_m > tolerance_m:
            self._settled_since = math.nan
            return False
        if math.isnan(self._settled_since):
            self._settled_since = t_s
        return t_s - self._settled_since >= self.plan.settle_s

    def _desired(self, t_s: float) -> DesiredState:
        seg = self._segment
        assert seg is not None
        elapsed = t_s - seg.start_s
        if self.phase == Phase.EXCITE:
            return self._excitation(elapsed, seg.q_to)
        if self.phase == Phase.DONE:
            zero = np.zeros(N_Q)
            return DesiredState(seg.q_to.copy(), zero, zero.copy())
        q, q_dot, q_ddot = min_jerk(elapsed, seg.duration_s, seg.q_from, seg.q_to, seg.v_from)
        return DesiredState(q, q_dot, q_ddot)

    def _excitation(self, elapsed_s: float, centre: FloatArray) -> DesiredState:
        """Arm swing and a horizontal circle under an envelope that fades in over the first
        period and out over the period after the stop, so q_d stays smooth (C2) and ends
        at rest at the centre."""
        p = self.plan
        period = p.excite_period_s
        w = 2.0 * math.pi / period
        env_in = _smoothstep(elapsed_s / period, period)
        stop = self._excite_stop_s - self._segment_start_s()
        env_out = _smoothstep((elapsed_s - stop) / period, period) if math.isfinite(stop) else None
        e, de, dde = env_in
        if env_out is not None:
            o, do, ddo = 1.0 - env_out[0], -env_out[1], -env_out[2]
            e, de, dde = e * o, de * o + e * do, dde * o + 2.0 * de * do + e * ddo
        s, c = math.sin(w * elapsed_s), math.cos(w * elapsed_s)
        f = np.zeros(N_Q)
        df = np.zeros(N_Q)
        ddf = np.zeros(N_Q)
        amp = np.zeros(N_Q)
        amp[X] = amp[Y] = p.excite_radius_m
        amp[ETA1], amp[ETA2] = p.excite_eta1_rad * self._swing, p.excite_eta2_rad * self._swing
        # x: r (1 - cos) keeps the circle through the centre; y: r sin; joints: sin.
        f[X], df[X], ddf[X] = 1.0 - c, w * s, w * w * c
        for row in (Y, ETA1, ETA2):
            f[row], df[row], ddf[row] = s, w * c, -w * w * s
        q = centre + amp * e * f
        q_dot = amp * (de * f + e * df)
        q_ddot = amp * (dde * f + 2.0 * de * df + e * ddf)
        return DesiredState(q, q_dot, q_ddot)

    def _segment_start_s(self) -> float:
        assert self._segment is not None
        return self._segment.start_s


def _smoothstep(x: float, scale_s: float) -> tuple[float, float, float]:
    """Quintic 0 -> 1 over x in [0, 1] and its first two time derivatives (x = t / scale)."""
    x = min(max(x, 0.0), 1.0)
    value = x**3 * (10.0 - 15.0 * x + 6.0 * x * x)
    rate = 30.0 * x**2 * (1.0 - x) ** 2 / scale_s
    accel = 60.0 * x * (1.0 - x) * (1.0 - 2.0 * x) / scale_s**2
    return value, rate, accel

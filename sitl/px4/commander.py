"""The PX4-like state machine: arming, modes, offboard proof of life, failsafe, landing.

Pure (simulation time in, decisions out), modelled on PX4 main's commander, failsafe
framework and navigator (``src/modules/commander``: ``Commander.cpp``,
``UserModeIntention.cpp``, ``ModeUtil/mode_requirements.cpp``, ``failsafe/failsafe.cpp``)
and on what the real SITL build did:

- **User intention and the mode flown.** DO_SET_MODE changes the user's intended mode; the
  mode flown is that one unless a failsafe replaces it. While disarmed every mode is
  accepted (PX4: "always allow mode change while disarmed"), even one that cannot run;
  armed, a mode is accepted only if it can run, else TEMPORARILY_REJECTED.
- **Mode requirements.** OFFBOARD needs the offboard signal; Hold (AUTO.LOITER) a global
  position (GPS, or motion capture after SET_GPS_GLOBAL_ORIGIN); Return (AUTO.RTL) a
  global position and home; Takeoff and Land a local position (always here); MANUAL,
  STABILIZED, ACRO, ALTCTL and POSCTL manual control (no RC here: never); MISSION a
  mission (never). Land and Return prevent arming.
- **Arming** (MAV_CMD_COMPONENT_ARM_DISARM): refused (TEMPORARILY_REJECTED) unless the
  battery is above BAT_CRIT_THR and the mode flown can run and does not prevent arming.
  PX4 runs these checks for every MAVLink arm command, forced (param2 21196) or not:
  force skips them only for commands from inside PX4. Home is set at arming. Disarming in
  the air is TEMPORARILY_REJECTED unless forced. After a disarm the intended mode returns
  to the last one asked for that neither prevents arming nor is Takeoff (measured: a
  take-off landed at once ends in Hold).
- **Offboard proof of life** (PX4 ``offboardCheck.cpp``): alive while ``now < t_last +
  COM_OF_LOSS_T``, ``t_last`` the time of the last valid SET_ATTITUDE_TARGET that does
  not ignore attitude.
- **Failsafe** (armed): while OFFBOARD is intended and the signal is lost, the vehicle
  flies the COM_OBL_RC_ACT action: 0 Position, 1 Altitude, 2 Stabilized (these need manual
  control, so they fall back to Return, as PX4 does without RC), 3 Return, 4 Land, 5 Hold,
  6 Terminate and 7 Disarm (both: disarm here). A Hold or Return that cannot run falls
  back to Return, then Land. When the signal returns, the vehicle flies OFFBOARD again;
  another mode asked for ends the failsafe.
- **Takeoff** (PX4 ``TakeoffHandling``): idle for COM_SPOOLUP_TIME after arming, then the
  climb velocity setpoint ramps over MPC_TKO_RAMP_T from -g / MPC_Z_VEL_P_ACC (no thrust)
  to MPC_TKO_SPEED, the vehicle lifting off on the way; climb to the takeoff height, then
  Hold ("Takeoff complete": the navigator makes Hold the intended mode).
- **Return**: climb to the return altitude above home (RTL_RETURN_ALT, or within
  RTL_MIN_DIST of home the height of the RTL_CONE_ANG cone over the distance, never below
  the current height), fly home, land there.
- **Land detection**: the measurement's ``on_ground`` (the world's ground contact), or,
  descending in Land or Return, a descent that stalls (vertical speed below 0.1 m/s for
  1 s).
- **Auto-disarm**: COM_DISARM_LAND after landing, or COM_SPOOLUP_TIME + COM_DISARM_PRFLT
  after arming without a takeoff (measured: 10 s asked, disarmed 10-11 s after arming).
- **A new global origin** (SET_GPS_GLOBAL_ORIGIN) resets the estimator's position (its
  reset counter grows by 3) and the arming checks fail for :data:`ORIGIN_SETTLE_S`
  ("horizontal position unstable", measured about 4 s on PX4).
- **Hover thrust**: the position controller flies with the hover thrust estimator's
  estimate once valid (:mod:`sitl.px4.hover_thrust`).

The setpoint is recomputed at each new estimate (the position loop runs at the
estimator's rate, as mc_pos_control does) and held between.

PX4 reports its decisions as events, not STATUSTEXT (measured: no STATUSTEXT on either
link); this commander writes them to :attr:`Commander.console`, as PX4 does to its log.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sitl.physics import AttitudeSetpoint
from sitl.physics.frames import (
    euler_from_rotation,
    rotation9_from_quaternion,
    rotation_from_quaternion,
)
from sitl.px4.geo import GeoReference
from sitl.px4.hover_thrust import HoverThrustEstimator
from sitl.px4.measurement import VehicleMeasurement
from sitl.px4.modes import Px4Mode
from sitl.px4.params import Px4Params
from sitl.px4.position_control import PositionController, PositionTarget
from sitl.px4.telemetry import Home

__all__ = ["BATTERY_CRITICAL", "FORCE_MAGIC", "Commander", "ConsoleLine"]

FORCE_MAGIC = 21196.0
"""MAV_CMD_COMPONENT_ARM_DISARM param2 that forces (dis)arming."""
BATTERY_CRITICAL = 0.07
"""PX4 BAT_CRIT_THR default: arming is refused below this remaining charge."""
LAND_STALL_SPEED_M_S = 0.1
"""Landing: vertical speed below which the descent counts as stalled [m/s]."""
LAND_STALL_TIME_S = 1.0
"""Landing: a stalled descent for this long counts as landed [s]."""
IN_AIR_HEIGHT_M = 1.0
"""Height above home from which the hover thrust estimator runs (PX4: dist_bottom > 1 m)."""
RTL_ARRIVED_M = 0.5
"""Return: horizontal distance to home at which the landing starts [m]."""
ORIGIN_SETTLE_S = 4.0
"""After a new global origin the arming checks fail this long [s] (PX4: 4.1 s measured)."""
ORIGIN_RESETS = 3
"""Estimator resets (ODOMETRY.reset_counter) a new global origin makes (measured)."""

_DEADLINE_EARLY_S = 1e-6
"""How much earlier than its sum a deadline of :meth:`Commander.next_deadline_s` is given
[s]: the rules compare differences (``now - since >= delay``), which may round otherwise."""

_CALL_RECORDS = frozenset({"_last_m", "_last_estimate_us", "_setpoint"})
"""What :meth:`Commander.update` and :meth:`Commander.setpoint` keep of their call: the
measurement, its estimate time and the setpoint returned. Called again with the same
measurement, they find them so (the estimate is not new, the setpoint is held) and decide
as before."""

_MANUAL_CONTROL = (
    Px4Mode.MANUAL, Px4Mode.STABILIZED, Px4Mode.ACRO, Px4Mode.ALTCTL, Px4Mode.POSCTL,
)  # fmt: skip
_PREVENT_ARMING = (Px4Mode.AUTO_LAND, Px4Mode.AUTO_RTL)
_POSITION_MODES = (Px4Mode.AUTO_TAKEOFF, Px4Mode.AUTO_LOITER, Px4Mode.AUTO_LAND, Px4Mode.AUTO_RTL)
_LOSS_ACTIONS = {3: Px4Mode.AUTO_RTL, 4: Px4Mode.AUTO_LAND, 5: Px4Mode.AUTO_LOITER}
"""COM_OBL_RC_ACT values with their own mode; 0, 1, 2 and unknown values need manual
control and fall back to Return; 6 and 7 disarm."""
_DISARM_ACTIONS = (6, 7)


@dataclass(frozen=True)
class ConsoleLine:
    """A line PX4 would print to its console (MAV_SEVERITY_* and the text)."""

    severity: int
    text: str


def _yaw(m: VehicleMeasurement) -> float:
    return euler_from_rotation(rotation_from_quaternion(m.quaternion_enu_flu_wxyz))[2]


class Commander:
    """Arming, modes, offboard, failsafe, return and landing; see the module docstring.

    Parameters
    ----------
    params : Px4Params
        Shared with the vehicle (PARAM_SET takes effect at once).
    gravity_m_s2 : float
        Gravity of the position controller [m/s^2].
    global_origin : GeoReference, optional
        The estimator's global origin at boot (GPS); None: no global position until
        :meth:`set_global_origin` (motion capture).
    initial_mode : Px4Mode
        Mode at boot (AUTO.LOITER: Hold).
    """

    def __init__(
        self,
        params: Px4Params,
        gravity_m_s2: float = 9.80665,
        global_origin: GeoReference | None = None,
        initial_mode: Px4Mode = Px4Mode.AUTO_LOITER,
    ) -> None:
        self._params = params
        self._g = float(gravity_m_s2)
        self._position = PositionController(params, gravity_m_s2)
        self._attitude_offboard = False
        """The last setpoint was OFFBOARD's attitude setpoint (the position loop idle)."""
        self._hover = HoverThrustEstimator(params)
        self.user_mode = initial_mode
        """The mode the user asked for (PX4's user intention)."""
        self.mode = initial_mode
        """The mode flown."""
        self.armed = False
        self.landed = True
        self.failsafe = False
        self.origin = global_origin
        """The estimator's global origin (None: no global position)."""
        self.home: Home | None = None
        self.console: list[ConsoleLine] = []
        """What PX4 would print; the runner drains it."""
        self._after_disarm = initial_mode
        self._armed_at_s = 0.0
        self._taken_off = False
        self._in_air = False
        self._landed_since_s: float | None = None
        self._stall_since_s: float | None = None
        self._offboard_sp: AttitudeSetpoint | None = None
        self._offboard_target: PositionTarget | None = None
        self._offboard_last_s = -math.inf
        self._target: PositionTarget | None = None
        self._target_mode: Px4Mode | None = None
        self._takeoff_up_m: float | None = None
        self._rtl_phase = 0
        self._rtl_up_m = 0.0
        self._takeoff_ramp = 1.0
        """Progress of the takeoff ramp in [0, 1] (1: no ramp, flying)."""
        self._prearm_battery = True
        self._origin_settled_s = -math.inf
        self.estimator_resets = 0
        """Resets of the estimate made here (a new global origin), on top of the
        estimator's own count."""
        self._last_m: VehicleMeasurement | None = None
        self._last_estimate_us: int | None = None
        self._setpoint: AttitudeSetpoint | None = None
        self._decided = operator.attrgetter(*(n for n in vars(self) if n not in _CALL_RECORDS))
        """Reads the attributes :meth:`decisions` holds (every one set above)."""

    # ---------------------------------------------------------------- queries

    @property
    def prearm_ok(self) -> bool:
        """Arming would pass its checks in the mode flown (HEARTBEAT STANDBY)."""
        return self._can_arm(self._last_now_s())

    def _last_now_s(self) -> float:
        return self._last_m.time_s if self._last_m is not None else 0.0

    def offboard_alive(self, now_s: float) -> bool:
        """The offboard stream is fresher than COM_OF_LOSS_T at ``now_s``."""
        return now_s < self._offboard_last_s + self._params["COM_OF_LOSS_T"]

    def can_run(self, mode: Px4Mode, now_s: float) -> bool:
        """Whether ``mode`` meets its requirements now (see the module docstring)."""
        if mode == Px4Mode.OFFBOARD:
            return self.offboard_alive(now_s)
        if mode == Px4Mode.AUTO_LOITER:
            return self.origin is not None
        if mode == Px4Mode.AUTO_RTL:
            return self.origin is not None and self.home is not None
        return mode in (Px4Mode.AUTO_TAKEOFF, Px4Mode.AUTO_LAND)

    @property
    def landed_state(self) -> int:
        """MAV_LANDED_STATE_* for EXTENDED_SYS_STATE."""
        if self.landed:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if self.armed and self.mode == Px4Mode.AUTO_TAKEOFF:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        if self.armed and self._descending:
            return mavlink.MAV_LANDED_STATE_LANDING
        return mavlink.MAV_LANDED_STATE_IN_AIR

    @property
    def _descending(self) -> bool:
        """Landing: AUTO.LAND, or the last phase of a return."""
        return self.mode == Px4Mode.AUTO_LAND or (
            self.mode == Px4Mode.AUTO_RTL and self._rtl_phase == 2
        )

    @property
    def setpoint_flown(self) -> AttitudeSetpoint | None:
        """The attitude setpoint of the last step (None while disarmed)."""
        return self._setpoint

    @property
    def hover_thrust(self) -> float:
        """The relative hover thrust the position controller flies with [-]."""
        return self._position.hover_thrust

    def decisions(self) -> tuple:
        """Everything :meth:`update` and :meth:`setpoint` decide, as the objects held now
        (and the console's length): two snapshots whose entries are the same objects mean
        that nothing was decided between them. What a call only keeps of its measurement
        and returns (:data:`_CALL_RECORDS`) is left out: a second call with the same
        measurement finds the same there."""
        return (*self._decided(self), len(self.console))

    def next_deadline_s(self, now_s: float) -> float:
        """The earliest simulated time [s] after ``now_s`` at which :meth:`update` may
        decide otherwise for the passing of time alone (the same measurement, no command):
        the offboard signal's loss, a stalled descent counting as landed, an auto-disarm
        (armed only); 1 us early, for the rounding of the sums; inf when none is ahead."""
        if not self.armed:
            return math.inf
        p = self._params
        deadline = math.inf
        if self.offboard_alive(now_s):
            deadline = self._offboard_last_s + p["COM_OF_LOSS_T"]
        if self._stall_since_s is not None and not self.landed:
            deadline = min(deadline, self._stall_since_s + LAND_STALL_TIME_S)
        rule = self._auto_disarm_rule()
        if rule is not None:
            since, delay, _ = rule
            if delay > 0.0:
                deadline = min(deadline, since + delay)
        return deadline - _DEADLINE_EARLY_S

    # -------------------------------------------------------------- commands

    def arm(self, now_s: float) -> int:
        """MAV_CMD_COMPONENT_ARM_DISARM param1 = 1 (forced or not); returns MAV_RESULT_*."""
        if self.armed:
            return mavlink.MAV_RESULT_ACCEPTED
        if not self._can_arm(now_s):
            self._print(
                mavlink.MAV_SEVERITY_WARNING, "Arming denied: Resolve system health failures first"
            )
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        self.armed = True
        self._armed_at_s = now_s
        self._taken_off = not self.landed
        self._takeoff_ramp = 0.0 if self.landed else 1.0
        self._landed_since_s = now_s if self.landed else None
        self._position.reset()
        if self.origin is not None and self._last_m is not None:
            self._set_home(self._last_m)
        self._print(mavlink.MAV_SEVERITY_INFO, "Armed by external command")
        return mavlink.MAV_RESULT_ACCEPTED

    def disarm(self, force: bool) -> int:
        """MAV_CMD_COMPONENT_ARM_DISARM param1 = 0; returns MAV_RESULT_*."""
        if not self.armed:
            return mavlink.MAV_RESULT_ACCEPTED
        if not self.landed and not force:
            self._print(mavlink.MAV_SEVERITY_CRITICAL, "Disarming denied: not landed")
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        self._disarm("external command")
        return mavlink.MAV_RESULT_ACCEPTED

    def request_mode(self, mode: Px4Mode, now_s: float) -> int:
        """DO_SET_MODE / SET_MODE to ``mode``; returns MAV_RESULT_*."""
        if self.armed and not self.can_run(mode, now_s):
            self._print(
                mavlink.MAV_SEVERITY_CRITICAL,
                f"Switching to {mode.display_name} is currently not available",
            )
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        if mode == Px4Mode.AUTO_TAKEOFF and mode != self.user_mode:
            self._takeoff_up_m = None
        self._intend(mode)
        return mavlink.MAV_RESULT_ACCEPTED

    def takeoff(self, up_m: float | None, now_s: float) -> int:
        """NAV_TAKEOFF to height ``up_m`` in the world [m], or to MIS_TAKEOFF_ALT above home
        when None; returns MAV_RESULT_*."""
        result = self.request_mode(Px4Mode.AUTO_TAKEOFF, now_s)
        if result == mavlink.MAV_RESULT_ACCEPTED:
            self._takeoff_up_m = up_m
            self._target = None
        return result

    def land(self, now_s: float) -> int:
        """NAV_LAND: land where the vehicle is; returns MAV_RESULT_*."""
        result = self.request_mode(Px4Mode.AUTO_LAND, now_s)
        if result == mavlink.MAV_RESULT_ACCEPTED:
            self._print(mavlink.MAV_SEVERITY_INFO, "Landing at current position")
        return result

    def offboard_setpoint(self, setpoint: AttitudeSetpoint, now_s: float) -> None:
        """Record a valid SET_ATTITUDE_TARGET (proof of life; flown only in OFFBOARD)."""
        self._offboard_sp = setpoint
        self._offboard_target = None
        self._offboard_last_s = now_s

    def offboard_position(self, target: PositionTarget, now_s: float) -> None:
        """Record a valid SET_POSITION_TARGET_LOCAL_NED (proof of life; in OFFBOARD the
        position controller flies it, with the hover thrust estimator, as in PX4's
        OFFBOARD position control)."""
        self._offboard_target = target
        self._offboard_sp = None
        self._offboard_last_s = now_s

    def set_global_origin(self, origin: GeoReference, now_s: float) -> bool:
        """SET_GPS_GLOBAL_ORIGIN at ``now_s``: the estimator takes ``origin`` (refused in the
        air, as EKF2 does) and resets; returns whether it did. Home follows at the next
        update; arming waits :data:`ORIGIN_SETTLE_S`."""
        if self.armed and not self.landed:
            return False
        self.origin = origin
        self.home = None
        self.estimator_resets += ORIGIN_RESETS
        self._origin_settled_s = now_s + ORIGIN_SETTLE_S
        return True

    # ------------------------------------------------------------ time steps

    def update(self, now_s: float, m: VehicleMeasurement) -> None:
        """Run the state machine at ``now_s``: checks, home, land detection, failsafe,
        takeoff completion, return phases and auto-disarm."""
        self._last_m = m
        self._prearm_battery = m.battery_remaining > BATTERY_CRITICAL
        if self.origin is not None and self.home is None:
            self._set_home(m)
        self._detect_landing(now_s, m)
        if self.armed:
            self._run_failsafe(now_s)
        else:
            self.mode = self.user_mode
            self.failsafe = False
        if self.armed and self.mode == Px4Mode.AUTO_TAKEOFF and not self.landed:
            self._complete_takeoff(m)
        if self.armed and self.mode == Px4Mode.AUTO_RTL:
            self._advance_return(m)
        self._auto_disarm(now_s)

    def setpoint(self, now_s: float, m: VehicleMeasurement) -> AttitudeSetpoint | None:
        """The attitude setpoint for this step (None while disarmed); the position loop
        runs once per new estimate and its setpoint is held in between."""
        if not self.armed:
            self._setpoint = None
            return None
        fresh = m.estimate_time_us != self._last_estimate_us
        now_us, last_us = m.estimate_time_us, self._last_estimate_us
        dt = 0.0 if now_us is None or last_us is None else (now_us - last_us) * 1e-6
        if self.mode == Px4Mode.OFFBOARD and self._offboard_sp is not None:
            self._setpoint = sp = self._offboard_sp
            self._attitude_offboard = True
            if fresh:
                self._last_estimate_us = m.estimate_time_us
                up = rotation9_from_quaternion(*(float(c) for c in sp.quaternion_wxyz))[8]
                self._estimate_hover_thrust(now_s, dt, m, sp.thrust * up)
            return sp
        if self._attitude_offboard:
            self._attitude_offboard = False
            self._position.reset()  # takes over from OFFBOARD's attitude setpoints
        if not fresh and self._setpoint is not None and self._target_mode == self.mode:
            return self._setpoint
        self._last_estimate_us = m.estimate_time_us
        target = self._current_target(m)
        spooling = now_s < self._armed_at_s + self._params["COM_SPOOLUP_TIME"]
        if self.landed and (self.mode != Px4Mode.AUTO_TAKEOFF or spooling):
            self._position.reset()
            self._setpoint = AttitudeSetpoint.from_euler(0.0, 0.0, target.yaw_rad, 0.0)
            return self._setpoint
        if self.landed:
            self._position.reset()  # PX4 keeps the integrators at zero on the ground
        cap = self._takeoff_climb_cap(dt)
        self._setpoint = self._position.update(
            target, m, min(dt, 0.1), climb_cap_m_s=cap, flying=self._takeoff_ramp >= 1.0
        )
        self._estimate_hover_thrust(now_s, dt, m, self._position.thrust_up)
        return self._setpoint

    def _takeoff_climb_cap(self, dt_s: float) -> float:
        """PX4's takeoff ramp: the climb velocity cap, from -g / MPC_Z_VEL_P_ACC (zero
        thrust) to MPC_TKO_SPEED over MPC_TKO_RAMP_T [m/s]; no cap once done."""
        if self._takeoff_ramp >= 1.0:
            return math.inf
        p = self._params
        ramp_s = p["MPC_TKO_RAMP_T"]
        self._takeoff_ramp = 1.0 if ramp_s <= dt_s else min(self._takeoff_ramp + dt_s / ramp_s, 1.0)
        start = -self._g / p["MPC_Z_VEL_P_ACC"]
        return start + self._takeoff_ramp * (p["MPC_TKO_SPEED"] - start)

    # -------------------------------------------------------------- internals

    def _can_arm(self, now_s: float) -> bool:
        return (
            self._prearm_battery
            and now_s >= self._origin_settled_s
            and self.mode not in _PREVENT_ARMING
            and self.can_run(self.mode, now_s)
        )

    def _intend(self, mode: Px4Mode) -> None:
        """The user asks for ``mode`` (a command, or the navigator after a takeoff)."""
        self.user_mode = mode
        if mode not in _PREVENT_ARMING and mode != Px4Mode.AUTO_TAKEOFF:
            self._after_disarm = mode
        self._fly(mode)
        self.failsafe = False

    def _fly(self, mode: Px4Mode) -> None:
        if mode != self.mode:
            self.mode = mode
            self._target = self._target_mode = None
            self._stall_since_s = None
            if mode == Px4Mode.AUTO_RTL:
                self._rtl_phase = 0

    def _run_failsafe(self, now_s: float) -> None:
        """The intended mode when it can run; else (offboard loss) the COM_OBL_RC_ACT action,
        or (any other mode) Return, each falling back as PX4's failsafe does."""
        intended = self.user_mode
        if self.can_run(intended, now_s):
            self._fly(intended)
            self.failsafe = False
            return
        mode = Px4Mode.AUTO_RTL
        if intended == Px4Mode.OFFBOARD:
            action = int(self._params["COM_OBL_RC_ACT"])
            if action in _DISARM_ACTIONS:
                self._disarm("failsafe")
                return
            mode = _LOSS_ACTIONS.get(action, Px4Mode.AUTO_RTL)
        if mode == Px4Mode.AUTO_LOITER and not self.can_run(mode, now_s):
            mode = Px4Mode.AUTO_RTL
        if mode == Px4Mode.AUTO_RTL and not self.can_run(mode, now_s):
            mode = Px4Mode.AUTO_LAND
        if not self.failsafe or mode != self.mode:
            self._print(mavlink.MAV_SEVERITY_WARNING, f"Failsafe activated: {mode.display_name}")
        self._fly(mode)
        self.failsafe = True

    def _set_home(self, m: VehicleMeasurement) -> None:
        pos = m.position_enu_m
        self.home = Home(float(pos[0]), float(pos[1]), float(pos[2]))

    def _current_target(self, m: VehicleMeasurement) -> PositionTarget:
        """The mode's position target, captured from ``m`` when the mode was entered (in
        OFFBOARD the latest position setpoint)."""
        if self.mode == Px4Mode.OFFBOARD and self._offboard_target is not None:
            self._target_mode = self.mode
            return self._offboard_target
        if self._target is not None and self._target_mode == self.mode:
            return self._target
        pos = m.position_enu_m
        east, north, up, yaw = float(pos[0]), float(pos[1]), float(pos[2]), _yaw(m)
        p = self._params
        if self.mode == Px4Mode.AUTO_TAKEOFF:
            if self._takeoff_up_m is None:
                base = self.home.up_m if self.home is not None else up
                goal = base + p["MIS_TAKEOFF_ALT"]
            else:
                goal = self._takeoff_up_m
            target = PositionTarget(
                east, north, max(goal, up), yaw, climb_limit_m_s=p["MPC_TKO_SPEED"]
            )
        elif self.mode == Px4Mode.AUTO_LAND:
            target = PositionTarget(
                east, north, None, yaw, climb_m_s=-p["MPC_LAND_SPEED"], smoothed=True
            )
        elif self.mode == Px4Mode.AUTO_RTL:
            target = self._return_target(m, yaw)
        else:
            target = PositionTarget(east, north, up, yaw)
        self._target, self._target_mode = target, self.mode
        return target

    def _return_target(self, m: VehicleMeasurement, yaw: float) -> PositionTarget:
        """The target of the return phase: 0 climb, 1 fly home, 2 land at home."""
        p = self._params
        home = self.home
        assert home is not None  # Return runs only with a home
        pos = m.position_enu_m
        distance = math.hypot(float(pos[0]) - home.east_m, float(pos[1]) - home.north_m)
        if self._rtl_phase == 0:
            height = p["RTL_RETURN_ALT"]
            if distance <= p["RTL_MIN_DIST"]:
                cone = math.radians(p["RTL_CONE_ANG"])
                if cone > 0.0:
                    height = min(height, distance / math.tan(cone))
            up = max(home.up_m + height, float(pos[2]))
            self._rtl_up_m = up
            return PositionTarget(float(pos[0]), float(pos[1]), up, yaw)
        if self._rtl_phase == 1:
            return PositionTarget(home.east_m, home.north_m, self._rtl_up_m, yaw)
        return PositionTarget(
            home.east_m, home.north_m, None, yaw, climb_m_s=-p["MPC_LAND_SPEED"], smoothed=True
        )

    def _advance_return(self, m: VehicleMeasurement) -> None:
        target = self._target
        if target is None or self._target_mode != Px4Mode.AUTO_RTL or self.home is None:
            return
        pos = m.position_enu_m
        if (
            self._rtl_phase == 0
            and abs(float(pos[2]) - self._rtl_up_m) < self._params["NAV_MC_ALT_RAD"]
        ):
            self._rtl_phase, self._target = 1, None
        elif self._rtl_phase == 1:
            gap = math.hypot(float(pos[0]) - self.home.east_m, float(pos[1]) - self.home.north_m)
            if gap < RTL_ARRIVED_M:
                self._rtl_phase, self._target = 2, None

    def _complete_takeoff(self, m: VehicleMeasurement) -> None:
        target = self._target
        if target is None or target.up_m is None or self._target_mode != Px4Mode.AUTO_TAKEOFF:
            return
        if abs(float(m.position_enu_m[2]) - target.up_m) < self._params["NAV_MC_ALT_RAD"]:
            self._intend(Px4Mode.AUTO_LOITER)
            self._target = PositionTarget(
                target.east_m, target.north_m, target.up_m, target.yaw_rad
            )
            self._target_mode = Px4Mode.AUTO_LOITER
            self._print(mavlink.MAV_SEVERITY_INFO, "Takeoff complete")

    def _estimate_hover_thrust(
        self, now_s: float, dt_s: float, m: VehicleMeasurement, thrust_up: float
    ) -> None:
        """Run the hover thrust estimator in the air, on the vertical component
        ``thrust_up`` [-] of the relative thrust setpoint flown (the position controller's,
        or OFFBOARD's attitude setpoint: PX4 estimates from the thrust setpoint whatever
        made it), and give its estimate, once valid, to the position controller. Measured
        on the PX4 build with our physics: a Land after a 0.42 kg payload was carried in
        OFFBOARD attitude descends at 0.69-0.74 m/s from its first second, so PX4 flies
        it with the payload's hover thrust already."""
        home_up = self.home.up_m if self.home is not None else 0.0
        if self.landed:
            self._in_air = False
        elif float(m.position_enu_m[2]) - home_up > IN_AIR_HEIGHT_M:
            self._in_air = True
        if not self._in_air or not (self.mode in _POSITION_MODES or self.mode == Px4Mode.OFFBOARD):
            self._hover.invalidate()
            return
        rot = rotation_from_quaternion(m.quaternion_enu_flu_wxyz)
        accel_up = float(rot[2] @ np.asarray(m.specific_force_flu_m_s2)) - self._g
        ve, vn, vu = m.velocity_enu_m_s.tolist()
        estimate = self._hover.update(now_s, dt_s, accel_up, thrust_up, (ve, vn, vu))
        if estimate.valid:
            flying = not self._attitude_offboard
            self._position.set_hover_thrust(estimate.hover_thrust, keep_thrust=flying)

    def _detect_landing(self, now_s: float, m: VehicleMeasurement) -> None:
        landed = m.on_ground
        if self._descending and self.armed and not landed:
            if abs(m.velocity_enu_m_s[2]) < LAND_STALL_SPEED_M_S:
                if self._stall_since_s is None:
                    self._stall_since_s = now_s
                landed = now_s - self._stall_since_s >= LAND_STALL_TIME_S
            else:
                self._stall_since_s = None
        if landed and not self.landed:
            self._landed_since_s = now_s
            self._print(mavlink.MAV_SEVERITY_INFO, "Landing detected")
        elif not landed:
            self._landed_since_s = None
            if self.armed and not self._taken_off:
                self._taken_off = True
                self._print(mavlink.MAV_SEVERITY_INFO, "Takeoff detected")
        self.landed = landed

    def _auto_disarm_rule(self) -> tuple[float, float, str] | None:
        """(since [s], delay [s], reason) of the auto-disarm that waits now, armed and
        landed: after landing, or after arming without a takeoff; None otherwise."""
        if not self.armed or self._landed_since_s is None:
            return None
        p = self._params
        if self._taken_off:
            return self._landed_since_s, p["COM_DISARM_LAND"], "landing"
        since = self._armed_at_s + p["COM_SPOOLUP_TIME"]
        return since, p["COM_DISARM_PRFLT"], "auto preflight disarming"

    def _auto_disarm(self, now_s: float) -> None:
        rule = self._auto_disarm_rule()
        if rule is None:
            return
        since, delay, reason = rule
        if delay > 0.0 and now_s - since >= delay:
            self._disarm(reason)

    def _disarm(self, reason: str) -> None:
        self.armed = False
        self._taken_off = False
        self._in_air = False
        self.failsafe = False
        self._hover.reset()
        self._position.set_hover_thrust(None)
        self.user_mode = self._after_disarm
        self._fly(self.user_mode)
        self._print(mavlink.MAV_SEVERITY_INFO, f"Disarmed by {reason}")

    def _print(self, severity: int, text: str) -> None:
        self.console.append(ConsoleLine(severity, text))

"""The PX4-like state machine: arming, modes, offboard proof of life, failsafe, landing.

Pure (simulation time in, decisions out), modelled on PX4's commander and navigator:

- Arming (MAV_CMD_COMPONENT_ARM_DISARM): refused (TEMPORARILY_REJECTED + STATUSTEXT)
  when the battery is below BAT_CRIT_THR (7 %), or in OFFBOARD without a live setpoint
  stream. Arming in the air is allowed. Disarming in the air is DENIED unless forced
  (param2 = 21196), as PX4 does for multicopters. Home is (re)set at arming.
- Modes: OFFBOARD, AUTO.TAKEOFF, AUTO.LOITER (Hold), AUTO.LAND and POSCTL (holds
  position: there are no sticks). OFFBOARD is TEMPORARILY_REJECTED unless the offboard
  stream is alive. MANUAL, STABILIZED, ACRO and ALTCTL need stick input, which this
  vehicle has not (TEMPORARILY_REJECTED, as PX4 without RC); MISSION, RTL and READY are
  not implemented (DENIED).
- Offboard proof of life (PX4 ``offboardCheck.cpp``): the stream is alive while
  ``now < t_last + COM_OF_LOSS_T`` where ``t_last`` is the simulation time of the last
  accepted SET_ATTITUDE_TARGET that does not ignore attitude. Loss while in OFFBOARD
  switches to the COM_OBL_RC_ACT mode (failsafe flag set until the next commanded mode).
- Takeoff: climb at MPC_TKO_SPEED to the takeoff height, then AUTO.LOITER at it once
  within NAV_MC_ALT_RAD ("Takeoff complete").
- Land detection: the measurement's ``on_ground`` (the world's ground contact), or, in
  AUTO.LAND, a descent that stalls (vertical speed below 0.1 m/s for 1 s).
- Auto-disarm: COM_DISARM_LAND seconds after landing, if the vehicle took off since arming.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

from sitl.physics import AttitudeSetpoint
from sitl.physics.frames import euler_from_rotation, rotation_from_quaternion
from sitl.px4.measurement import VehicleMeasurement
from sitl.px4.modes import Px4Mode
from sitl.px4.params import OFFBOARD_LOSS_ACTIONS, Px4Params
from sitl.px4.position_control import PositionController, PositionTarget

__all__ = ["BATTERY_CRITICAL", "FORCE_MAGIC", "Commander", "Home", "StatusText"]

FORCE_MAGIC = 21196.0
"""MAV_CMD_COMPONENT_ARM_DISARM param2 that forces (dis)arming."""
BATTERY_CRITICAL = 0.07
"""PX4 BAT_CRIT_THR default: arming is refused below this remaining charge."""
LAND_STALL_SPEED_M_S = 0.1
"""AUTO.LAND: vertical speed below which the descent counts as stalled [m/s]."""
LAND_STALL_TIME_S = 1.0
"""AUTO.LAND: a stalled descent for this long counts as landed [s]."""

_MANUAL_INPUT_MODES = (Px4Mode.MANUAL, Px4Mode.STABILIZED, Px4Mode.ACRO, Px4Mode.ALTCTL)
_HOLD_MODES = (Px4Mode.AUTO_LOITER, Px4Mode.POSCTL)
_LOSS_MODES = {0: Px4Mode.POSCTL, 4: Px4Mode.AUTO_LAND, 5: Px4Mode.AUTO_LOITER}
assert set(_LOSS_MODES) == set(OFFBOARD_LOSS_ACTIONS)


@dataclass(frozen=True)
class Home:
    """Home: where the vehicle was last armed (world ENU [m])."""

    east_m: float
    north_m: float
    up_m: float


@dataclass(frozen=True)
class StatusText:
    """A STATUSTEXT to send on every link (MAV_SEVERITY_* and at most 50 characters)."""

    severity: int
    text: str


def _yaw(m: VehicleMeasurement) -> float:
    return euler_from_rotation(rotation_from_quaternion(m.quaternion_enu_flu_wxyz))[2]


class Commander:
    """Arming, mode, offboard and landing logic; see the module docstring.

    Parameters
    ----------
    params : Px4Params
        Shared with the vehicle (PARAM_SET takes effect at once).
    gravity_m_s2 : float
        Gravity of the position controller [m/s^2].
    initial_mode : Px4Mode
        Mode at boot (AUTO.LOITER: Hold).
    """

    def __init__(
        self,
        params: Px4Params,
        gravity_m_s2: float = 9.80665,
        initial_mode: Px4Mode = Px4Mode.AUTO_LOITER,
    ) -> None:
        self._params = params
        self._position = PositionController(params, gravity_m_s2)
        self.mode = initial_mode
        self.armed = False
        self.landed = True
        self.failsafe = False
        self.home: Home | None = None
        self.outbox: list[StatusText] = []
        self.state_changed = False
        self._taken_off = False
        self._landed_since_s: float | None = None
        self._stall_since_s: float | None = None
        self._offboard_sp: AttitudeSetpoint | None = None
        self._offboard_last_s = -math.inf
        self._target: PositionTarget | None = None
        self._takeoff_up_m: float | None = None
        self._home_pending = True
        self._prearm_ok = True
        self._last_time_s: float | None = None

    # ---------------------------------------------------------------- queries

    @property
    def prearm_ok(self) -> bool:
        """Arming checks pass (battery above BAT_CRIT_THR) at the last update."""
        return self._prearm_ok

    def offboard_alive(self, now_s: float) -> bool:
        """The offboard stream is fresher than COM_OF_LOSS_T at ``now_s``."""
        return now_s < self._offboard_last_s + self._params["COM_OF_LOSS_T"]

    @property
    def landed_state(self) -> int:
        """MAV_LANDED_STATE_* for EXTENDED_SYS_STATE."""
        if self.landed:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if self.armed and self.mode == Px4Mode.AUTO_TAKEOFF:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        if self.armed and self.mode == Px4Mode.AUTO_LAND:
            return mavlink.MAV_LANDED_STATE_LANDING
        return mavlink.MAV_LANDED_STATE_IN_AIR

    # -------------------------------------------------------------- commands

    def arm(self, now_s: float, force: bool) -> int:
        """MAV_CMD_COMPONENT_ARM_DISARM param1 = 1; returns MAV_RESULT_*."""
        if self.armed:
            return mavlink.MAV_RESULT_ACCEPTED
        if not force:
            if not self._prearm_ok:
                return self._deny("Arming denied: battery critical")
            if self.mode == Px4Mode.OFFBOARD and not self.offboard_alive(now_s):
                return self._deny("Arming denied: no offboard signal")
        self.armed = True
        self._taken_off = not self.landed
        self._home_pending = True
        self._position.reset()
        self._changed()
        self.outbox.append(StatusText(mavlink.MAV_SEVERITY_INFO, "Armed by external command"))
        return mavlink.MAV_RESULT_ACCEPTED

    def disarm(self, force: bool) -> int:
        """MAV_CMD_COMPONENT_ARM_DISARM param1 = 0; returns MAV_RESULT_*."""
        if not self.armed:
            return mavlink.MAV_RESULT_ACCEPTED
        if not self.landed and not force:
            self.outbox.append(
                StatusText(mavlink.MAV_SEVERITY_CRITICAL, "Disarming denied: not landed")
            )
            return mavlink.MAV_RESULT_DENIED
        self._disarm("Disarmed by external command")
        return mavlink.MAV_RESULT_ACCEPTED

    def request_mode(self, mode: Px4Mode, now_s: float) -> int:
        """DO_SET_MODE / SET_MODE to ``mode``; returns MAV_RESULT_*."""
        if mode in _MANUAL_INPUT_MODES:
            return self._deny(f"Switching to {mode.display_name} denied: no manual control")
        if mode == Px4Mode.OFFBOARD and not self.offboard_alive(now_s):
            return self._deny("Switching to Offboard denied: no offboard signal")
        if mode == Px4Mode.AUTO_TAKEOFF:
            return self.takeoff(None)
        if mode not in (Px4Mode.OFFBOARD, Px4Mode.AUTO_LAND, *_HOLD_MODES):
            self.outbox.append(
                StatusText(mavlink.MAV_SEVERITY_CRITICAL, f"{mode.display_name} not available")
            )
            return mavlink.MAV_RESULT_DENIED
        self._enter(mode)
        return mavlink.MAV_RESULT_ACCEPTED

    def takeoff(self, up_m: float | None) -> int:
        """NAV_TAKEOFF (or AUTO.TAKEOFF) to height ``up_m`` in the world [m], or to
        MIS_TAKEOFF_ALT above home when None; returns MAV_RESULT_*."""
        self._takeoff_up_m = up_m
        self._enter(Px4Mode.AUTO_TAKEOFF)
        return mavlink.MAV_RESULT_ACCEPTED

    def offboard_setpoint(self, setpoint: AttitudeSetpoint, now_s: float) -> None:
        """Record a valid SET_ATTITUDE_TARGET (proof of life; applied only in OFFBOARD)."""
        self._offboard_sp = setpoint
        self._offboard_last_s = now_s

    # ------------------------------------------------------------ time steps

    def update(self, now_s: float, m: VehicleMeasurement) -> None:
        """Run the timers at ``now_s``: home, land detection, takeoff completion, offboard
        loss failsafe and auto-disarm."""
        self._prearm_ok = m.battery_remaining > BATTERY_CRITICAL
        if self._home_pending and (self.armed or self.home is None):
            pos = m.position_enu_m
            self.home = Home(float(pos[0]), float(pos[1]), float(pos[2]))
            self._home_pending = self.home is None
        self._detect_landing(now_s, m)
        if self.mode == Px4Mode.OFFBOARD and not self.offboard_alive(now_s):
            action = int(self._params["COM_OBL_RC_ACT"])
            self._enter(_LOSS_MODES[action])
            self.failsafe = True
            self.outbox.append(
                StatusText(
                    mavlink.MAV_SEVERITY_CRITICAL,
                    f"Failsafe: no offboard, {self.mode.display_name}",
                )
            )
        disarm_after = self._params["COM_DISARM_LAND"]
        if (
            self.armed
            and self._taken_off
            and disarm_after > 0.0
            and self._landed_since_s is not None
            and now_s - self._landed_since_s >= disarm_after
        ):
            self._disarm("Disarmed by landing")

    def setpoint(self, now_s: float, m: VehicleMeasurement) -> AttitudeSetpoint | None:
        """The attitude setpoint for this step (None while disarmed)."""
        dt = 0.0 if self._last_time_s is None else max(now_s - self._last_time_s, 0.0)
        self._last_time_s = now_s
        if not self.armed:
            return None
        if self.mode == Px4Mode.OFFBOARD and self._offboard_sp is not None:
            return self._offboard_sp
        target = self._current_target(m)
        if self.landed and self.mode != Px4Mode.AUTO_TAKEOFF:
            self._position.reset()
            return AttitudeSetpoint.from_euler(0.0, 0.0, target.yaw_rad, 0.0)
        if self.mode == Px4Mode.AUTO_TAKEOFF and target.up_m is not None:
            if abs(m.position_enu_m[2] - target.up_m) < self._params["NAV_MC_ALT_RAD"]:
                self._enter(Px4Mode.AUTO_LOITER, hold=target)
                self.outbox.append(StatusText(mavlink.MAV_SEVERITY_INFO, "Takeoff complete"))
        return self._position.update(target, m, dt)

    # -------------------------------------------------------------- internals

    def _current_target(self, m: VehicleMeasurement) -> PositionTarget:
        """The mode's position target, captured from ``m`` when the mode was entered."""
        if self._target is not None:
            return self._target
        pos = m.position_enu_m
        east, north, up, yaw = float(pos[0]), float(pos[1]), float(pos[2]), _yaw(m)
        if self.mode == Px4Mode.AUTO_TAKEOFF:
            if self._takeoff_up_m is None:
                base = self.home.up_m if self.home is not None else up
                goal = base + self._params["MIS_TAKEOFF_ALT"]
            else:
                goal = self._takeoff_up_m
            self._target = PositionTarget(
                east, north, max(goal, up), yaw, climb_limit_m_s=self._params["MPC_TKO_SPEED"]
            )
        elif self.mode == Px4Mode.AUTO_LAND:
            self._target = PositionTarget(
                east, north, None, yaw, climb_m_s=-self._params["MPC_LAND_SPEED"]
            )
        else:
            self._target = PositionTarget(east, north, up, yaw)
        return self._target

    def _enter(self, mode: Px4Mode, hold: PositionTarget | None = None) -> None:
        self._target = None
        if hold is not None:
            self._target = PositionTarget(hold.east_m, hold.north_m, hold.up_m, hold.yaw_rad)
        if mode != self.mode:
            self.mode = mode
            self._changed()
        self.failsafe = False
        self._stall_since_s = None

    def _detect_landing(self, now_s: float, m: VehicleMeasurement) -> None:
        landed = m.on_ground
        if self.mode == Px4Mode.AUTO_LAND and self.armed and not landed:
            if abs(m.velocity_enu_m_s[2]) < LAND_STALL_SPEED_M_S:
                if self._stall_since_s is None:
                    self._stall_since_s = now_s
                landed = now_s - self._stall_since_s >= LAND_STALL_TIME_S
            else:
                self._stall_since_s = None
        if landed and not self.landed:
            self._landed_since_s = now_s
        elif not landed:
            self._landed_since_s = None
            if self.armed:
                self._taken_off = True
        if landed != self.landed:
            self.landed = landed
            self._changed()
        if self.landed and self._landed_since_s is None:
            self._landed_since_s = now_s

    def _disarm(self, reason: str) -> None:
        self.armed = False
        self._taken_off = False
        self._changed()
        self.outbox.append(StatusText(mavlink.MAV_SEVERITY_INFO, reason))

    def _deny(self, text: str) -> int:
        self.outbox.append(StatusText(mavlink.MAV_SEVERITY_CRITICAL, text))
        return mavlink.MAV_RESULT_TEMPORARILY_REJECTED

    def _changed(self) -> None:
        self.state_changed = True

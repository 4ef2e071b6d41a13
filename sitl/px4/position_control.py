"""The PX4-like position controller of the AUTO modes (takeoff, hold, land) and POSCTL.

A reduced PX4 ``PositionControl`` (``src/modules/mc_pos_control/PositionControl``), written
in ENU (the cascade is frame covariant, so PX4's per-axis gains carry over):

1. position P: ``v_sp = MPC_XY_P (p_sp - p) + v_ff`` horizontally (norm clipped to
   MPC_XY_VEL_MAX) and ``MPC_Z_P (z_sp - z) + v_ff,z`` vertically (clipped to
   [-MPC_Z_VEL_MAX_DN, MPC_Z_VEL_MAX_UP], and to a climb limit such as MPC_TKO_SPEED); a
   target without a height is velocity-only vertically (AUTO.LAND descends at v_ff,z);
2. velocity PI: ``a_sp = a_ff + K_P (v_sp - v) + K_I integral(v_sp - v) dt`` with the
   MPC_*_VEL_P_ACC / MPC_*_VEL_I_ACC gains and the target's acceleration feed-forward
   ``a_ff`` (an OFFBOARD trajectory setpoint's; zero in the AUTO modes); the vertical
   integral learns the hover-thrust
   error (e.g. a grasped payload), both integrals are clipped to +-INTEGRAL_LIMIT_M_S2;
3. acceleration to thrust (PX4 ``_accelerationControl``): the thrust axis is
   ``normalize(a_x, a_y, g)`` (tilt limited to MPC_TILTMAX_AIR), the relative collective
   thrust is ``Th (1 + a_z / g) / cos(tilt)`` clipped to [MPC_THR_MIN, MPC_THR_MAX], with
   the hover thrust Th the hover thrust estimator's when valid, else MPC_THR_HOVER
   (constrained to [MPC_THR_MIN, MPC_THR_MAX]); a change of Th moves the vertical integral
   so that the thrust does not jump (PX4 ``updateHoverThrust``);
4. attitude: the thrust axis and the held yaw give roll and pitch (ZYX Euler angles).

A target whose climb is ``smoothed`` (the descents of AUTO.LAND and Return) reaches its
vertical velocity as PX4's AUTO flight task does (``FlightTaskAuto``'s jerk-limited
trajectory, ``VelocitySmoothing``): the velocity setpoint moves with at most MPC_JERK_AUTO
jerk and MPC_ACC_DOWN_MAX (going down) or MPC_ACC_UP_MAX (going up) acceleration, starting
from the measured velocity and the last acceleration setpoint, and its acceleration is
the feed-forward. Measured on the PX4 build (SIH hexacopter, a Land commanded while
climbing at 2.6 m/s): the climb stops in about 1.2 s and the descent reaches 0.7 m/s 1.5 s
later, without overshoot; a stepped setpoint overshoots under a heavy payload. Position
targets are not smoothed, and there is no velocity D term (PX4's MPC_XY_VEL_D_ACC): the
gains are PX4's defaults, not tuned to this vehicle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sitl.physics import AttitudeSetpoint
from sitl.px4.measurement import VehicleMeasurement
from sitl.px4.params import Px4Params

__all__ = ["INTEGRAL_LIMIT_M_S2", "PositionController", "PositionTarget"]

INTEGRAL_LIMIT_M_S2 = 5.0
"""Clip of each velocity-integral component [m/s^2]: about half of g, enough for a payload
of half the vehicle's weight."""


@dataclass(frozen=True)
class PositionTarget:
    """What the position controller holds or tracks (world ENU).

    Attributes
    ----------
    east_m, north_m : float
        Horizontal position setpoint [m].
    up_m : float or None
        Height setpoint [m]; None tracks the vertical velocity ``climb_m_s`` only.
    yaw_rad : float
        Heading setpoint, ZYX yaw about z up from east [rad].
    climb_m_s : float
        Vertical velocity feed-forward [m/s] (up positive).
    climb_limit_m_s : float
        Largest climb velocity setpoint [m/s] (on top of MPC_Z_VEL_MAX_UP).
    velocity_m_s : (float, float)
        Horizontal velocity feed-forward (east, north) [m/s].
    acceleration_m_s2 : (float, float, float)
        Acceleration feed-forward (east, north, up) [m/s^2].
    smoothed : bool
        ``climb_m_s`` is reached through PX4's jerk-limited trajectory (a target without a
        height in the AUTO modes), not stepped to.
    """

    east_m: float
    north_m: float
    up_m: float | None
    yaw_rad: float
    climb_m_s: float = 0.0
    climb_limit_m_s: float = math.inf
    velocity_m_s: tuple[float, float] = (0.0, 0.0)
    acceleration_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    smoothed: bool = False


class PositionController:
    """Position + velocity cascade to an :class:`~sitl.physics.AttitudeSetpoint`.

    Parameters
    ----------
    params : Px4Params
        Read at every update, so PARAM_SET takes effect at once.
    gravity_m_s2 : float
        Gravity [m/s^2] (PX4: CONSTANTS_ONE_G).
    """

    def __init__(self, params: Px4Params, gravity_m_s2: float = 9.80665) -> None:
        self._params = params
        self._g = float(gravity_m_s2)
        self._integral = [0.0, 0.0, 0.0]
        self._hover: float | None = None
        self._acc_up_m_s2 = 0.0
        self._climb: tuple[float, float] | None = None
        """The smoothed climb: velocity [m/s] and acceleration [m/s^2], up; None when the
        last target was not smoothed."""
        self.thrust_up = 0.0
        """Vertical component of the last relative thrust setpoint [-] (the hover thrust
        estimator's input)."""

    def reset(self) -> None:
        """Zero the velocity integrals (when the controller takes over)."""
        self._integral = [0.0, 0.0, 0.0]

    @property
    def hover_thrust(self) -> float:
        """The relative hover thrust the controller flies with [-]."""
        if self._hover is None:
            return self._parameter_hover()
        return self._hover

    def _parameter_hover(self) -> float:
        p = self._params
        return min(max(p["MPC_THR_HOVER"], p["MPC_THR_MIN"]), p["MPC_THR_MAX"])

    def set_hover_thrust(self, hover: float | None, keep_thrust: bool = True) -> None:
        """Fly with hover thrust ``hover`` (None: MPC_THR_HOVER); ``keep_thrust`` moves the
        vertical integral so that the thrust of the last setpoint is kept (PX4
        ``PositionControl::updateHoverThrust``; not while another setpoint flies)."""
        previous = self.hover_thrust
        self._hover = hover
        new = self.hover_thrust
        if keep_thrust and new != previous:
            g, a = self._g, self._acc_up_m_s2
            self._integral[2] += (a + g) * previous / new - g - a

    @property
    def smoothed_climb(self) -> tuple[float, float] | None:
        """The jerk-limited climb setpoint: velocity [m/s] and acceleration [m/s^2], up;
        None while the target is not smoothed."""
        return self._climb

    @property
    def integral_m_s2(self) -> tuple[float, float, float]:
        """Velocity-integral acceleration (east, north, up) [m/s^2]."""
        return (self._integral[0], self._integral[1], self._integral[2])

    def update(
        self,
        target: PositionTarget,
        m: VehicleMeasurement,
        dt_s: float,
        climb_cap_m_s: float = math.inf,
        flying: bool = True,
    ) -> AttitudeSetpoint:
        """One controller step of ``dt_s`` seconds toward ``target`` from measurement ``m``;
        the climb velocity setpoint is capped at ``climb_cap_m_s`` [m/s] after every other
        limit (PX4's takeoff ramp, which starts below zero). Not ``flying`` (taking off),
        the thrust may go down to zero, as PX4's (MPC_THR_MIN applies in flight)."""
        p = self._params
        pos = m.position_enu_m.tolist()
        vel = m.velocity_enu_m_s.tolist()
        vx = p["MPC_XY_P"] * (target.east_m - pos[0]) + target.velocity_m_s[0]
        vy = p["MPC_XY_P"] * (target.north_m - pos[1]) + target.velocity_m_s[1]
        horizontal = math.hypot(vx, vy)
        if horizontal > p["MPC_XY_VEL_MAX"]:
            scale = p["MPC_XY_VEL_MAX"] / horizontal
            vx, vy = vx * scale, vy * scale
        vz, az_ff = target.climb_m_s, target.acceleration_m_s2[2]
        if target.smoothed and target.up_m is None:
            vz, smoothed_az = self._smooth_climb(vz, vel[2], dt_s)
            az_ff += smoothed_az
        else:
            self._climb = None
        if target.up_m is not None:
            vz += p["MPC_Z_P"] * (target.up_m - pos[2])
        up_limit = min(p["MPC_Z_VEL_MAX_UP"], target.climb_limit_m_s)
        vz = min(max(vz, -p["MPC_Z_VEL_MAX_DN"]), up_limit, climb_cap_m_s)

        errors = (vx - vel[0], vy - vel[1], vz - vel[2])
        gains_p = (p["MPC_XY_VEL_P_ACC"], p["MPC_XY_VEL_P_ACC"], p["MPC_Z_VEL_P_ACC"])
        gains_i = (p["MPC_XY_VEL_I_ACC"], p["MPC_XY_VEL_I_ACC"], p["MPC_Z_VEL_I_ACC"])
        acc = []
        for i in range(3):
            self._integral[i] = min(
                max(self._integral[i] + gains_i[i] * errors[i] * dt_s, -INTEGRAL_LIMIT_M_S2),
                INTEGRAL_LIMIT_M_S2,
            )
            feed_forward = az_ff if i == 2 else target.acceleration_m_s2[i]
            acc.append(feed_forward + gains_p[i] * errors[i] + self._integral[i])
        self._acc_up_m_s2 = acc[2]
        return self._attitude(acc, target.yaw_rad, p["MPC_THR_MIN"] if flying else 0.0)

    def _smooth_climb(self, goal_m_s: float, climb_m_s: float, dt_s: float) -> tuple[float, float]:
        """One step of the jerk-limited climb toward ``goal_m_s`` [m/s, up]: the velocity
        setpoint [m/s] and its acceleration [m/s^2]. It starts from the measured climb
        ``climb_m_s`` and the last acceleration setpoint; the acceleration heads for the
        largest from which MPC_JERK_AUTO still brings it to zero at the goal."""
        p = self._params
        jerk = p["MPC_JERK_AUTO"]
        if self._climb is None:
            limit = (-p["MPC_ACC_DOWN_MAX"], p["MPC_ACC_UP_MAX"])
            self._climb = (climb_m_s, min(max(self._acc_up_m_s2, limit[0]), limit[1]))
        v, a = self._climb
        gap = goal_m_s - v
        step = jerk * dt_s
        if abs(gap) <= 0.5 * step * dt_s and abs(a) <= step:
            self._climb = (goal_m_s, 0.0)  # there within this step: no chatter about it
            return self._climb
        most = p["MPC_ACC_UP_MAX"] if gap > 0.0 else p["MPC_ACC_DOWN_MAX"]
        wanted = math.copysign(min(most, math.sqrt(2.0 * jerk * abs(gap))), gap)
        a += min(max(wanted - a, -step), step)
        v += a * dt_s
        self._climb = (v, a)
        return v, a

    def _attitude(self, acc: list[float], yaw_rad: float, thrust_min: float) -> AttitudeSetpoint:
        """Thrust axis, tilt limit and collective thrust of an ENU acceleration setpoint."""
        p = self._params
        ax, ay, az = acc
        g = self._g
        norm = math.sqrt(ax * ax + ay * ay + g * g)
        zx, zy, zz = ax / norm, ay / norm, g / norm
        tilt_max = math.radians(p["MPC_TILTMAX_AIR"])
        if math.acos(min(zz, 1.0)) > tilt_max:
            h = math.hypot(zx, zy)
            zx, zy, zz = (
                zx / h * math.sin(tilt_max),
                zy / h * math.sin(tilt_max),
                math.cos(tilt_max),
            )
        thrust = self.hover_thrust * (1.0 + az / g) / zz
        thrust = min(max(thrust, thrust_min), p["MPC_THR_MAX"])
        self.thrust_up = thrust * zz
        cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
        x_h = cy * zx + sy * zy
        y_h = -sy * zx + cy * zy
        phi = math.asin(max(-1.0, min(1.0, -y_h)))
        theta = math.atan2(x_h, zz)
        return AttitudeSetpoint.from_euler(phi, theta, yaw_rad, thrust)

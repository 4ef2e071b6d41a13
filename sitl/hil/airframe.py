"""The PX4 airframe of a scenario's hexacopter, for PX4 flying our physics (``simulator_mavlink``).

PX4 starts with the hexa-X airframe 3011 (``jsbsim_hexarotor_x``: six motors on outputs 1-6,
``PWM_MAIN_FUNCn = 100 + n``, MAV_TYPE 13, no SIH, no Gazebo: PX4 connects to an external
simulator) and every parameter below replaces what that file sets:

- **rotor geometry**: ``CA_ROTOR_COUNT`` 6 and, per rotor i of :mod:`sitl.physics.rotors`
  (FLU, azimuth 30 deg + 60 deg i counter-clockwise from body x, spins alternating from
  counter-clockwise), ``CA_ROTORi_PX/PY/PZ`` = its hub in PX4's body frame FRD [m],
  ``CA_ROTORi_KM`` = +k_m for a counter-clockwise rotor and -k_m for a clockwise one (PX4:
  the reaction moment about FRD z is ``CT * KM * u``) and ``CA_ROTORi_CT`` = the rotor's
  believed full thrust [N]. PX4's output i is then our rotor i: motor command
  ``HIL_ACTUATOR_CONTROLS.controls[i]`` drives rotor i;
- **thrust model**: ``THR_MDL_FAC`` = the motors' curve (``vehicle.rotors.thr_mdl_fac``), so
  that PX4's relative thrust is linear in newtons; ``MPC_THR_HOVER`` = the relative thrust
  that holds vehicle and arm (mass from the scenario) in a hover;
- **tuning**: the parameters the imitation (:class:`sitl.px4.Px4Params`) flies with, which
  are PX4 main's defaults except the scenario's attitude and rate gains
  (``[plant.attitude_control]``) and THR_MDL_FAC; so the airframe file's own gains
  (MC_ROLL_P 6, MPC_XY_VEL_P_ACC 3, ...) do not stay. MAV_SYS_ID stays PX4's (instance + 1);
- **navigation** (:func:`navigation_parameters`): EKF2 on motion capture alone, or on GPS
  and barometer;
- **the low-battery action** the README asks of the vehicle's PX4: ``COM_LOW_BAT_ACT`` 3,
  Return at the critical level and Land at the emergency one (PX4's default, 0, only warns);
- **the world's overrides** (``[world] autopilot_params``), last.

Plain data and geometry: no I/O, independent of ``companion.model``.
"""

from __future__ import annotations

from collections.abc import Mapping

from companion.frames import frd_from_flu
from sitl.physics.rotors import N_ROTORS, RotorGeometry
from sitl.px4 import Px4Params
from sitl.scenario import Scenario

__all__ = [
    "AUTOSTART",
    "EV_CTRL_HPOS_VPOS_YAW",
    "HGT_REF_GNSS",
    "HGT_REF_VISION",
    "LOW_BATTERY_ACTION",
    "NAVIGATION_MODES",
    "hover_relative_thrust",
    "navigation_parameters",
    "px4_parameters",
    "rotor_parameters",
]

AUTOSTART = 3011
"""SYS_AUTOSTART of PX4's hexa-X airframe for an external simulator (``jsbsim_hexarotor_x``)."""
NAVIGATION_MODES = ("mocap", "gps")
"""What EKF2 navigates on: motion capture (external vision) or GPS and barometer."""
EV_CTRL_HPOS_VPOS_YAW = 1 | 2 | 8
"""EKF2_EV_CTRL: fuse vision horizontal position, vertical position and yaw."""
HGT_REF_GNSS = 1
"""EKF2_HGT_REF: the GNSS height is EKF2's height reference."""
HGT_REF_VISION = 3
"""EKF2_HGT_REF: the vision height is EKF2's height reference."""
LOW_BATTERY_ACTION = 3
"""``COM_LOW_BAT_ACT``: Return at the critical battery level, Land at the emergency one."""
_NOT_FROM_THE_IMITATION = ("MAV_SYS_ID", "IMU_INTEG_RATE", "IMU_GYRO_RATEMAX")
"""Parameters of the imitation's table that PX4 sets per instance or that the simulator's
IMU rate sets (:func:`px4_parameters`)."""


def rotor_parameters(scenario: Scenario) -> dict[str, float]:
    """``CA_ROTOR_COUNT`` and the ``CA_ROTORi_*`` geometry of the scenario's six rotors
    (module docstring), rotor i of :mod:`sitl.physics.rotors` as PX4's rotor i."""
    rotors = scenario.vehicle.rotors
    geometry = RotorGeometry.hexa_x(rotors.arm_length_m, rotors.yaw_moment_per_thrust_m)
    params: dict[str, float] = {"CA_AIRFRAME": 0, "CA_ROTOR_COUNT": N_ROTORS}
    for i in range(N_ROTORS):
        px, py, pz = frd_from_flu(geometry.positions_m[i]).tolist()
        params[f"CA_ROTOR{i}_PX"] = round(px, 6)
        params[f"CA_ROTOR{i}_PY"] = round(py, 6)
        params[f"CA_ROTOR{i}_PZ"] = round(pz, 6)
        params[f"CA_ROTOR{i}_KM"] = round(
            float(geometry.spin[i]) * rotors.yaw_moment_per_thrust_m, 6
        )
        params[f"CA_ROTOR{i}_CT"] = rotors.max_thrust_per_rotor_n
    return params


def hover_relative_thrust(scenario: Scenario) -> float:
    """The relative collective thrust (0-1, PX4's thrust setpoint) that holds vehicle and
    empty arm in a hover, with the believed maximum thrust of the six rotors."""
    arm = scenario.arm
    mass_kg = scenario.vehicle.mass_kg + arm.link1.mass_kg + arm.link2.mass_kg
    full_n = N_ROTORS * scenario.vehicle.rotors.max_thrust_per_rotor_n
    return mass_kg * scenario.environment.gravity_m_s2 / full_n


def navigation_parameters(
    navigation: str,
    *,
    vision_delay_s: float = 0.0,
    gps_delay_s: float = 0.0,
    gps_position_std_m: float | None = None,
) -> dict[str, float]:
    """EKF2's parameters for navigating on motion capture or on GPS.

    ``mocap`` (the paper's lab, as :func:`sitl.px4_sitl.mocap.mocap_parameters` measured on
    PX4 SIH):
    GPS and range finder off; vision position (horizontal and vertical) and yaw fused,
    vision as the height reference, the barometer fused beside it (the height and climb
    rate that carry EKF2 through a motion-capture dropout: without it a 10 s dropout ended
    in a blind descent touching down at 1.03 m/s, with it at 0.76 m/s, measured on the
    build), the poses' own variances bounded below by
    EKF2's minimum noises (10 mm, 0.05 rad); ``EKF2_EV_DELAY`` = ``vision_delay_s``, the
    pose's age when PX4 receives it.

    ``gps``: EKF2's GPS and barometer defaults, ``EKF2_GPS_DELAY`` = ``gps_delay_s``; with
    ``gps_position_std_m`` (an RTK receiver: centimetres) EKF2's GPS noise floors
    (``EKF2_GPS_P_NOISE``, default 0.5 m, and ``EKF2_GPS_V_NOISE``) come down to the
    receiver's and the GNSS height is the reference, as an RTK user configures it.

    Raises ValueError for an unknown navigation mode.
    """
    if navigation == "mocap":
        return {
            "EKF2_GPS_CTRL": 0,
            "EKF2_BARO_CTRL": 1,
            "EKF2_RNG_CTRL": 0,
            "EKF2_EV_CTRL": EV_CTRL_HPOS_VPOS_YAW,
            "EKF2_HGT_REF": HGT_REF_VISION,
            "EKF2_EV_NOISE_MD": 0,
            "EKF2_EVP_NOISE": 0.01,
            "EKF2_EVA_NOISE": 0.05,
            "EKF2_EV_DELAY": round(vision_delay_s * 1e3, 1),
        }
    if navigation == "gps":
        params: dict[str, float] = {"EKF2_GPS_DELAY": round(gps_delay_s * 1e3, 1)}
        if gps_position_std_m is not None:
            params["EKF2_GPS_P_NOISE"] = max(gps_position_std_m, 0.01)
            params["EKF2_GPS_V_NOISE"] = 0.05
            params["EKF2_HGT_REF"] = HGT_REF_GNSS
        return params
    raise ValueError(f"navigation must be one of {NAVIGATION_MODES}, got {navigation!r}")


def px4_parameters(
    scenario: Scenario,
    navigation: Mapping[str, float],
    *,
    imu_rate_hz: float,
) -> dict[str, float]:
    """Every parameter PX4 gets for the scenario's vehicle (module docstring): the
    imitation's table, the rotor geometry, the hover thrust, the IMU rate, the navigation
    parameters ``navigation`` (:func:`navigation_parameters`), then the world's overrides."""
    imitated = Px4Params.from_scenario(scenario)
    params: dict[str, float] = {
        name: imitated[name] for name in imitated.names if name not in _NOT_FROM_THE_IMITATION
    }
    params.update(rotor_parameters(scenario))
    params["MPC_THR_HOVER"] = round(hover_relative_thrust(scenario), 4)
    params["IMU_INTEG_RATE"] = round(imu_rate_hz)
    params["COM_LOW_BAT_ACT"] = LOW_BATTERY_ACTION
    params.update(navigation)
    if scenario.world is not None:
        params.update(scenario.world.autopilot_params)
    return params

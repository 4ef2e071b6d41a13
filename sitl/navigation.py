"""What the simulated autopilot knows of its own state: noisy, delayed, sampled truth.

Stands in for PX4's EKF2 output. Position and attitude come from a
:class:`~sitl.sensors.PoseSensor` (the motion-capture / vision fix the paper flies with),
body rates from a :class:`~sitl.sensors.GyroSensor`, each at its configured rate, noise
and latency (scenario ``[sensors]``) and held between samples; velocity is the truth
(EKF2's velocity is smooth, its noise far below the pose noise); the accelerometer reads
the truth specific force. Nothing here reaches the companion except through MAVLink.
"""

from __future__ import annotations

import numpy as np

from companion.config import Scenario
from sitl.physics.frames import quaternion_from_euler
from sitl.px4.measurement import VehicleMeasurement
from sitl.sensors import GyroSensor, PoseSensor
from sitl.world import World

__all__ = ["Navigation"]


class Navigation:
    """Sampled, noisy vehicle state for the simulated autopilot.

    Parameters
    ----------
    scenario
        Sensor rates, noise and latency (``[sensors]``).
    rng
        Seeded generator, the only source of randomness.
    noise
        ``False`` for exact, undelayed measurements at every step.
    """

    def __init__(self, scenario: Scenario, rng: np.random.Generator, *, noise: bool = True) -> None:
        s = scenario.sensors
        self._noise = noise
        self._pose = PoseSensor(
            rng,
            position_std_m=s.position_std_m,
            attitude_std_rad=s.attitude_std_rad,
            rate_hz=s.pose_rate_hz,
            latency_s=s.pose_latency_s,
        )
        self._gyro = GyroSensor(rng, rate_std_rad_s=s.gyro_std_rad_s, rate_hz=s.gyro_rate_hz)
        self._position: np.ndarray | None = None
        self._quaternion: np.ndarray | None = None
        self._omega: np.ndarray | None = None

    def measure(self, world: World) -> VehicleMeasurement:
        """The measurement at the world's current time."""
        state = world.state
        if not self._noise:
            self._position = np.array(state.q[0:3])
            self._quaternion = np.array(state.quaternion_wxyz)
            self._omega = np.array(state.omega_body_rad_s)
        else:
            pose = self._pose.sample(state.time_s, state.q)
            if pose is not None or self._position is None:
                if pose is None:
                    self._position = np.array(state.q[0:3])
                    self._quaternion = np.array(state.quaternion_wxyz)
                else:
                    self._position = np.array(pose.position_m)
                    self._quaternion = quaternion_from_euler(*pose.euler_rad.tolist())
            gyro = self._gyro.sample(state.time_s, state.omega_body_rad_s)
            if gyro is not None or self._omega is None:
                self._omega = np.array(
                    state.omega_body_rad_s if gyro is None else gyro.omega_body_rad_s
                )
        assert self._quaternion is not None and self._omega is not None
        return VehicleMeasurement(
            time_s=state.time_s,
            position_enu_m=self._position,
            velocity_enu_m_s=state.q_dot[0:3],  # copied by VehicleMeasurement
            quaternion_enu_flu_wxyz=self._quaternion,
            omega_flu_rad_s=self._omega,
            specific_force_flu_m_s2=world.specific_force_flu_m_s2(),
            on_ground=world.on_ground,
            battery_voltage_v=world.battery.voltage_v,
            battery_remaining=world.battery.remaining,
        )

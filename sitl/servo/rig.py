"""A bench rig for simulated servos: each shaft drives a rotational inertia, in real time.

Neither servo emulator moves its own shaft: the shaft angle comes from a physics joint
through :class:`~sitl.servo.xm430.ServoJoint`. :class:`JointRig` is the smallest such
physics, for bench tests and benchmarks without the full SITL plant: a background thread
steps each servo and integrates ``inertia * rate_dot = torque - damping * rate`` with
semi-implicit Euler over the measured wall time (at most ``max_step_s`` at once), under
the emulator's lock, at about ``rate_hz``. Run the emulator with its own stepping off
(``step_servos=False`` / ``step_actuators=False``) so only the rig advances time.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping

from sitl.servo.xm430 import ServoJoint

__all__ = ["JointRig"]


class JointRig:
    """Servo shafts, each on its own inertia with viscous damping, stepped by a thread.

    Parameters
    ----------
    servos
        The servos (ServoJoint), by id.
    lock
        The lock the servos' emulator holds while it touches them.
    inertia_kg_m2
        Inertia on each shaft [kg m^2].
    damping_n_m_s
        Viscous damping on each shaft [N m s/rad].
    rate_hz
        Target stepping rate [Hz].
    max_step_s
        Longest time step integrated at once [s].
    """

    def __init__(
        self,
        servos: Mapping[int, ServoJoint],
        lock: threading.Lock,
        *,
        inertia_kg_m2: float = 0.01,
        damping_n_m_s: float = 0.05,
        rate_hz: float = 1000.0,
        max_step_s: float = 0.005,
    ) -> None:
        if not (inertia_kg_m2 > 0.0 and damping_n_m_s >= 0.0 and rate_hz > 0.0):
            raise ValueError("need inertia > 0, damping >= 0 and rate > 0")
        self.servos = dict(servos)
        self.lock = lock
        self.inertia_kg_m2 = inertia_kg_m2
        self.damping_n_m_s = damping_n_m_s
        self._period_s = 1.0 / rate_hz
        self._max_step_s = max_step_s
        self.angle_rad = dict.fromkeys(self.servos, 0.0)
        """Shaft angle per servo [rad]."""
        self.rate_rad_s = dict.fromkeys(self.servos, 0.0)
        """Shaft rate per servo [rad/s]."""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def set_state(self, servo_id: int, angle_rad: float, rate_rad_s: float = 0.0) -> None:
        """Put a shaft at an angle [rad] turning at a rate [rad/s]."""
        with self.lock:
            self.angle_rad[servo_id] = angle_rad
            self.rate_rad_s[servo_id] = rate_rad_s
            self.servos[servo_id].set_state(angle_rad, rate_rad_s)

    def step(self, dt_s: float) -> None:
        """Advance every servo and shaft by ``dt_s`` [s] (the lock is held by the caller)."""
        for servo_id, servo in self.servos.items():
            servo.step(dt_s)
            rate = self.rate_rad_s[servo_id]
            accel = (servo.torque_n_m() - self.damping_n_m_s * rate) / self.inertia_kg_m2
            rate += accel * dt_s
            angle = self.angle_rad[servo_id] + rate * dt_s
            self.rate_rad_s[servo_id], self.angle_rad[servo_id] = rate, angle
            servo.set_state(angle, rate)

    def start(self) -> None:
        """Start stepping in a background thread."""
        if self._thread is not None:
            raise RuntimeError("the rig is already running")
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="joint-rig", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread; safe to call twice."""
        if self._thread is None:
            return
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._thread = None

    def __enter__(self) -> JointRig:
        self.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def _run(self) -> None:
        last = time.monotonic()
        while not self._stop.wait(self._period_s):
            now = time.monotonic()
            with self.lock:
                self.step(min(now - last, self._max_step_s))
            last = now

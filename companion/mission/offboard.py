"""The OFFBOARD handover with PX4 as an explicit state: what the control loop streams.

PX4 flies the last SET_ATTITUDE_TARGET the moment it accepts OFFBOARD, and its HEARTBEAT
(a strict 1 Hz stream) shows the mode up to 1 s later. So what is streamed is a state of
its own (:class:`Stream`), changed only along :data:`TRANSITIONS`:

``OFF``      nothing is streamed; PX4 flies its own modes (take-off, hold, land).
``HOLD``     the handover: the attitude the vehicle has and the hover thrust of the model,
             fresh every cycle, so what PX4 flies at the switch is what it already does.
``CONTROL``  from the COMMAND_ACK of OFFBOARD on (not the next heartbeat): the
             controller's setpoints.
``LEVEL``    the way out in the air: level at the current yaw with the model's hover
             thrust, until PX4 acknowledges the landing or hold command.
``GROUND``   the way out on the ground: level with the thrust floor (no tilt, no lift).

When PX4's position controller flies the vehicle (the ``px4_position`` baseline), the air
stages stream SET_POSITION_TARGET_LOCAL_NED instead (:meth:`Offboard.position_setpoint`):
``HOLD`` and ``LEVEL`` the position the vehicle has at rest (zero velocity and
acceleration: PX4 brakes and holds there), ``CONTROL`` the mission's desired position,
velocity and acceleration; ``GROUND`` stays the attitude setpoint with the thrust floor.

:class:`HoldBias` is what PX4's Hold needed horizontally before the handover, the force
the controller's trim starts from. Pure: no I/O, no clock; times are vehicle time [s].
"""

from __future__ import annotations

import math
from collections import deque
from enum import StrEnum

import numpy as np
from numpy.typing import NDArray

from companion.control.laws import DesiredState
from companion.control.setpoints import (
    AttitudeThrustSetpoint,
    PositionSetpoint,
    ThrustModel,
    fixed_setpoint,
)
from companion.coordinates import PHI, POSITION, PSI, THETA
from companion.link.telemetry import VehicleStatus

__all__ = ["TRANSITIONS", "HoldBias", "Offboard", "Stream", "StreamTransitionError"]

FloatArray = NDArray[np.float64]


class Stream(StrEnum):
    """What the control loop streams to PX4 (see the module docstring)."""

    OFF = "off"
    HOLD = "hold"
    CONTROL = "control"
    LEVEL = "level"
    GROUND = "ground"


TRANSITIONS: dict[Stream, frozenset[Stream]] = {
    Stream.OFF: frozenset({Stream.HOLD, Stream.LEVEL, Stream.GROUND}),
    Stream.HOLD: frozenset({Stream.CONTROL, Stream.LEVEL, Stream.GROUND, Stream.OFF}),
    Stream.CONTROL: frozenset({Stream.LEVEL, Stream.GROUND, Stream.OFF}),
    Stream.LEVEL: frozenset({Stream.OFF}),
    Stream.GROUND: frozenset({Stream.OFF}),
}
"""Allowed changes: into the handover only from OFF; into CONTROL only from the handover;
out of the air (LEVEL, GROUND) from anywhere but the other way out; OFF from anywhere."""

_SHOW_MODE_S = 0.2
"""Time PX4 needs to show a mode change in its next HEARTBEAT [s]."""


class StreamTransitionError(RuntimeError):
    """A change of stream outside :data:`TRANSITIONS` (a bug in the sequence)."""


class Offboard:
    """The stream state and the vehicle time OFFBOARD was accepted at."""

    def __init__(self) -> None:
        self.stream = Stream.OFF
        self.accepted_s = math.nan
        """Vehicle time of the OFFBOARD acknowledgement [s] (NaN before)."""

    @property
    def flying(self) -> bool:
        """PX4 flies the controller's setpoints."""
        return self.stream == Stream.CONTROL

    def to(self, stream: Stream) -> None:
        """Change what is streamed; OFF is always allowed, others along TRANSITIONS."""
        if stream == self.stream:
            return
        if stream not in TRANSITIONS[self.stream]:
            raise StreamTransitionError(f"stream {self.stream.value} -> {stream.value}")
        self.stream = stream

    def accept(self, t_s: float) -> None:
        """PX4 acknowledged OFFBOARD at vehicle time ``t_s`` [s]: stream the controller."""
        self.to(Stream.CONTROL)
        self.accepted_s = t_s

    def setpoint(
        self,
        control: AttitudeThrustSetpoint,
        q: FloatArray,
        weight_n: float,
        thrust: ThrustModel,
    ) -> AttitudeThrustSetpoint | None:
        """The setpoint of the current stage; None: nothing to send.

        ``control`` is the controller's setpoint, ``q`` the measured state (ENU/FLU,
        ZYX Euler angles in q[3:6]), ``weight_n`` the hover thrust the model believes [N].
        """
        yaw = float(q[PSI])
        if self.stream == Stream.CONTROL:
            return control
        if self.stream == Stream.HOLD:
            return fixed_setpoint(float(q[PHI]), float(q[THETA]), yaw, weight_n, thrust)
        if self.stream == Stream.LEVEL:
            return fixed_setpoint(0.0, 0.0, yaw, weight_n, thrust)
        if self.stream == Stream.GROUND:
            return fixed_setpoint(0.0, 0.0, yaw, 0.0, thrust)
        return None

    def position_setpoint(self, q: FloatArray, desired: DesiredState) -> PositionSetpoint | None:
        """The position setpoint of the current stage when PX4's position controller flies
        the vehicle; None where the stage streams an attitude (``GROUND``) or nothing.

        ``q`` is the measured state, ``desired`` the mission's desired state and its rates
        (ENU, yaw about z up in index PSI).
        """
        if self.stream == Stream.CONTROL:
            return PositionSetpoint(
                _vec3(desired.q[POSITION]), _vec3(desired.q_dot[POSITION]),
                _vec3(desired.q_ddot[POSITION]), float(desired.q[PSI]),
            )  # fmt: skip
        if self.stream in (Stream.HOLD, Stream.LEVEL):
            zero = (0.0, 0.0, 0.0)
            return PositionSetpoint(_vec3(q[POSITION]), zero, zero, float(q[PSI]))
        return None

    def left(self, status: VehicleStatus | None) -> bool:
        """A heartbeat sent after PX4 had time to show OFFBOARD shows another mode."""
        if status is None or status.time_boot_ms is None:
            return False
        after_s = status.time_boot_ms * 1e-3 - self.accepted_s
        return after_s > _SHOW_MODE_S and status.mode.name != "OFFBOARD"


def _vec3(v: FloatArray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])


class HoldBias:
    """The horizontal force PX4's Hold needed beside the vehicle's acceleration, world x, y
    [N], over the last ``window_s`` of vehicle time before the handover: mean thrust force
    minus mass x mean acceleration. PX4's velocity integrator answers with it to the same
    bias of the attitude estimate that the controller's trim learns; starting the trim from
    it keeps the handover from letting go of that force (without it the vehicle drifted
    15-20 cm off at the switch on PX4 SIH, tilt change 6 deg)."""

    def __init__(self, window_s: float = 3.0) -> None:
        self.window_s = window_s
        self._samples: deque[tuple[float, FloatArray, FloatArray]] = deque()

    def record(self, t_s: float, force_xy_n: FloatArray, velocity_xy_m_s: FloatArray) -> None:
        """One sample: vehicle time [s], horizontal thrust force [N], velocity [m/s]."""
        self._samples.append((t_s, np.array(force_xy_n), np.array(velocity_xy_m_s)))
        while t_s - self._samples[0][0] > self.window_s:
            self._samples.popleft()

    def force_n(self, mass_kg: float) -> FloatArray:
        """The bias [N], world x, y; zero without two samples."""
        if len(self._samples) < 2:
            return np.zeros(2)
        (t0, _, v0), (t1, _, v1) = self._samples[0], self._samples[-1]
        force: FloatArray = np.mean([f for _, f, _ in self._samples], axis=0)
        if t1 - t0 <= 0.0:
            return force
        return force - mass_kg * (v1 - v0) / (t1 - t0)

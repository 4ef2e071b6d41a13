"""Control authority of the simulated vehicle at hover: how much body torque it can make.

An arm that swings a payload loads the vehicle's pitch axis with its reaction torque and
the shift of the combined CoM; if that exceeds what the mixer can produce around hover,
no outer-loop controller can track the trajectory (docs/validation.md). This
module measures that limit on the truth plant's own rotor model and PX4-like mixer, which
allocates relative thrust and linearizes it per motor with the autopilot's THR_MDL_FAC
(here the scenario's ``vehicle.rotors.thr_mdl_fac``, a configured airframe).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sitl.physics.rotors import (
    RotorGeometry,
    SequentialDesaturationMixer,
    inverse_thrust_curve,
    thrust_curve,
)
from sitl.scenario import Scenario

__all__ = ["Authority", "hover_authority"]

_SWEEP = np.linspace(0.0, 3.0, 601)
"""Normalized torque commands tried per axis and direction (beyond 1 to reach saturation)."""


@dataclass(frozen=True)
class Authority:
    """Torque limits at hover, body frame FLU (roll about x, pitch about y, yaw about z)."""

    mass_kg: float
    hover_thrust_n: float
    hover_relative_thrust: float
    """Relative collective thrust that hovers: the SET_ATTITUDE_TARGET thrust [-]."""
    hover_command: float
    """Motor command u that hovers (after PX4's THR_MDL_FAC linearization) [-]."""
    unsaturated_torque_n_m: tuple[float, float, float]
    """Largest body torque magnitude per axis before the mixer reports saturation (a rotor
    at 0 or 1): what a PX4 rate loop with anti-windup can hold [N m]."""
    max_torque_n_m: tuple[float, float, float]
    """Largest torque magnitude per axis with saturated rotors, while the total thrust stays
    at least the hover thrust (else the vehicle sinks) [N m]."""
    torque_per_normalized_n_m: tuple[float, float, float]
    """Body torque per unit normalized torque of PX4's allocation, unsaturated, at the
    believed maximum thrust [N m]: what ``[controller.attitude_feedforward]
    torque_per_normalized_n_m`` takes (roll, pitch)."""


def hover_authority(scenario: Scenario, payload_attached: bool) -> Authority:
    """Sweep the normalized torque of each axis at the hover thrust and measure the body
    torque the six (truth) rotors produce after the mixer's desaturation and PX4's
    linearization, up to the point where the mixer starts to give up collective thrust."""
    rotors = scenario.vehicle.rotors
    mass = scenario.vehicle.mass_kg + scenario.arm.link1.mass_kg + scenario.arm.link2.mass_kg
    if payload_attached:
        mass += scenario.payload.mass_kg
    hover = mass * scenario.environment.gravity_m_s2
    true_max = rotors.max_thrust_per_rotor_n * scenario.plant.thrust_mismatch
    geometry = RotorGeometry.hexa_x(rotors.arm_length_m, rotors.yaw_moment_per_thrust_m)
    mixer = SequentialDesaturationMixer(geometry, rotors.max_thrust_per_rotor_n)
    wrench = geometry.wrench_matrix()[:3]
    relative_hover = hover / (6.0 * true_max)
    f = rotors.thr_mdl_fac
    u_hover = float(inverse_thrust_curve(relative_hover, f))
    unsaturated, maximum = [math.inf] * 3, [0.0] * 3
    for axis in range(3):
        for sign in (1.0, -1.0):
            free, best = 0.0, 0.0
            for c in _SWEEP:
                command = [0.0, 0.0, 0.0]
                command[axis] = sign * float(c)
                out = mixer.mix(command, relative_hover)
                u = inverse_thrust_curve(out.relative_thrusts, f)
                thrusts = true_max * thrust_curve(u, f)
                if thrusts.sum() < hover * (1.0 - 1e-9):
                    break  # the mixer now trades collective thrust for torque
                torque = sign * float(wrench[axis] @ thrusts)
                best = max(best, torque)
                if not (out.saturation_positive[axis] or out.saturation_negative[axis]):
                    free = max(free, torque)
            unsaturated[axis] = min(unsaturated[axis], free)
            maximum[axis] = max(maximum[axis], best) if sign > 0 else min(maximum[axis], best)
    per_unit = mixer.torque_per_normalized_n_m.tolist()
    return Authority(
        mass_kg=mass,
        hover_thrust_n=hover,
        hover_relative_thrust=relative_hover,
        hover_command=u_hover,
        unsaturated_torque_n_m=(unsaturated[0], unsaturated[1], unsaturated[2]),
        max_torque_n_m=(maximum[0], maximum[1], maximum[2]),
        torque_per_normalized_n_m=(per_unit[0], per_unit[1], per_unit[2]),
    )

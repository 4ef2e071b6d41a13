"""The PX4 parameters the companion's model depends on, and whether they fit the config.

The flight app reads these from the vehicle before it arms (pure checks here, the reading
in :mod:`companion.mission.app`):

============== ========================================================================
THR_MDL_FAC    PX4 linearizes the relative thrust of SET_ATTITUDE_TARGET per motor with
               it; the force is ``relative x max thrust`` only if it equals the motors'
               curve, ``vehicle.rotors.thr_mdl_fac``
               (:class:`companion.control.setpoints.ThrustModel`)
MPC_THR_MIN    PX4's smallest thrust in flight: the companion's thrust floor (attitude
               authority with airmode off)
CA_ROTOR_COUNT the rotors PX4 allocates to; the config's maximum thrust is that of six
COM_OF_LOSS_T  how long PX4 flies on without a setpoint (reported, not checked)
MC_ROLL_P,     PX4's attitude gains: the bandwidth the companion's tilt commands are
MC_PITCH_P     followed with (reported in the flight log)
MC_*RATE_P,    PX4's roll and pitch rate PI, its gain K and integrator limits: with
_I, _K,        ``[controller.attitude_feedforward]`` the companion inverts PX4's tilt loop
MC_RR_INT_LIM, (:mod:`companion.control.attitude_feedforward`), so these and MC_ROLL_P, MC_PITCH_P
MC_PR_INT_LIM  must be the config's (checked only then)
MC_BAT_SCALE_EN PX4 scales its thrust and torque setpoints up as the battery's voltage
               falls; the companion carries the thrust scale with the voltage itself
               (``[estimator.thrust_scale] window_s``), so the two must not both
               compensate: refused while the companion does
============== ========================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from companion.config import AttitudeFeedforward, CompanionConfig

__all__ = ["ATTITUDE_LOOP", "OPTIONAL", "REQUIRED", "VehicleParams", "contradictions"]

REQUIRED = ("THR_MDL_FAC", "MPC_THR_MIN")
"""Parameters every PX4 the companion flies must answer."""
ATTITUDE_LOOP = (
    *("MC_ROLLRATE_P", "MC_PITCHRATE_P", "MC_ROLLRATE_I", "MC_PITCHRATE_I"),
    *("MC_ROLLRATE_K", "MC_PITCHRATE_K", "MC_RR_INT_LIM", "MC_PR_INT_LIM"),
)
"""PX4's roll and pitch rate loop, which the attitude feed-forward models."""
OPTIONAL = (
    *("CA_ROTOR_COUNT", "COM_OF_LOSS_T", "MC_ROLL_P", "MC_PITCH_P", "MC_BAT_SCALE_EN"),
    *ATTITUDE_LOOP,
)
"""Parameters checked or reported when the vehicle has them (older PX4 has no CA_*)."""
GAIN_TOLERANCE = 0.02
"""Largest relative difference between a PX4 gain and the config's model of it [-]."""
N_ROTORS = 6
THR_MDL_FAC_TOLERANCE = 0.02
"""Largest difference between the vehicle's THR_MDL_FAC and the config's [-]."""


@dataclass(frozen=True)
class VehicleParams:
    """Values read from the vehicle (None: it has no such parameter)."""

    thr_mdl_fac: float
    thrust_min_relative: float
    rotor_count: int | None = None
    offboard_loss_timeout_s: float | None = None
    roll_p: float | None = None
    pitch_p: float | None = None
    attitude_loop: dict[str, float] = field(default_factory=dict)
    """The :data:`ATTITUDE_LOOP` parameters the vehicle answered, by name."""
    battery_scaling: bool | None = None
    """MC_BAT_SCALE_EN: PX4 scales its setpoints with the battery's voltage."""

    @classmethod
    def from_values(cls, values: dict[str, float | None]) -> VehicleParams:
        """From ``{name: value}`` of :data:`REQUIRED` and :data:`OPTIONAL` (KeyError when a
        required one is missing or None)."""
        required = {name: values[name] for name in REQUIRED}
        missing = [name for name, value in required.items() if value is None]
        if missing:
            raise KeyError(", ".join(missing))
        count = values.get("CA_ROTOR_COUNT")
        scaling = values.get("MC_BAT_SCALE_EN")
        return cls(
            thr_mdl_fac=float(required["THR_MDL_FAC"]),  # type: ignore[arg-type]
            thrust_min_relative=float(required["MPC_THR_MIN"]),  # type: ignore[arg-type]
            rotor_count=None if count is None else int(count),
            offboard_loss_timeout_s=values.get("COM_OF_LOSS_T"),
            roll_p=values.get("MC_ROLL_P"),
            pitch_p=values.get("MC_PITCH_P"),
            attitude_loop={
                name: float(value)
                for name in ATTITUDE_LOOP
                if (value := values.get(name)) is not None
            },
            battery_scaling=None if scaling is None else scaling != 0.0,
        )

    def describe(self) -> str:
        """One line for the flight log."""
        parts = [f"THR_MDL_FAC {self.thr_mdl_fac:g}", f"MPC_THR_MIN {self.thrust_min_relative:g}"]
        for label, value in (
            ("CA_ROTOR_COUNT", self.rotor_count),
            ("COM_OF_LOSS_T", self.offboard_loss_timeout_s),
            ("MC_ROLL_P", self.roll_p),
            ("MC_PITCH_P", self.pitch_p),
        ):
            if value is not None:
                parts.append(f"{label} {value:g}")
        return ", ".join(parts)


def contradictions(params: VehicleParams, scenario: CompanionConfig) -> list[str]:
    """Why the vehicle does not fit the scenario's model (empty: it does), one sentence each."""
    out = []
    fac = scenario.vehicle.rotors.thr_mdl_fac
    if abs(params.thr_mdl_fac - fac) > THR_MDL_FAC_TOLERANCE:
        out.append(
            f"the vehicle's THR_MDL_FAC is {params.thr_mdl_fac:g} but the config's "
            f"vehicle.rotors.thr_mdl_fac is {fac:g}: PX4 linearizes the thrust with its own "
            "value, so the relative thrust would not make the force the model predicts; set "
            f"THR_MDL_FAC to {fac:g} on the vehicle (or correct the config to its motors)"
        )
    if params.rotor_count is not None and params.rotor_count != N_ROTORS:
        out.append(
            f"the vehicle's CA_ROTOR_COUNT is {params.rotor_count}, the config describes a "
            f"hexacopter ({N_ROTORS} x {scenario.vehicle.rotors.max_thrust_per_rotor_n:g} N)"
        )
    if not 0.0 <= params.thrust_min_relative < 1.0:
        out.append(f"the vehicle's MPC_THR_MIN {params.thrust_min_relative:g} is not in [0, 1)")
    scale = scenario.estimator.thrust_scale
    if params.battery_scaling and scale is not None and scale.window_s > 0.0:
        out.append(
            "the vehicle scales its thrust with the battery's voltage (MC_BAT_SCALE_EN = 1), "
            "and so does the companion ([estimator.thrust_scale] window_s carries the thrust "
            "scale with the voltage it reports): set MC_BAT_SCALE_EN to 0 on the vehicle, or "
            "window_s to 0 in the config to hold the thrust scale from the grasp"
        )
    feedforward = scenario.controller.attitude_feedforward
    if feedforward is not None:
        out.extend(_attitude_loop_contradictions(params, feedforward))
    return out


def _attitude_loop_contradictions(params: VehicleParams, model: AttitudeFeedforward) -> list[str]:
    """Where PX4's roll/pitch loop is not the one ``[controller.attitude_feedforward]``
    inverts (the offsets would then be wrong by the ratio of the gains)."""
    answered = {**params.attitude_loop, "MC_ROLL_P": params.roll_p, "MC_PITCH_P": params.pitch_p}
    loop = {name: value for name, value in answered.items() if value is not None}
    missing = [n for n in ("MC_ROLL_P", "MC_PITCH_P", *ATTITUDE_LOOP) if n not in loop]
    if missing:
        return [
            f"the vehicle does not answer {', '.join(missing)}, which "
            "[controller.attitude_feedforward] models; remove that section to fly without it"
        ]
    out = []
    for axis, (name, rate) in enumerate((("ROLL", "RR"), ("PITCH", "PR"))):
        k = loop[f"MC_{name}RATE_K"]
        expected = (  # (parameter, the section's key, its value, scaled by the rate K)
            (f"MC_{name}_P", "attitude_p", model.attitude_p[axis], False),
            (f"MC_{name}RATE_P", "rate_p", model.rate_p[axis], True),
            (f"MC_{name}RATE_I", "rate_i", model.rate_i[axis], True),
            (
                f"MC_{rate}_INT_LIM",
                "rate_integrator_limit",
                model.rate_integrator_limit[axis],
                False,
            ),
        )
        for param, key, configured, scaled in expected:
            value = loop[param]
            vehicle = value * k if scaled else value
            if not math.isclose(vehicle, configured, rel_tol=GAIN_TOLERANCE, abs_tol=1e-6):
                times = f" x MC_{name}RATE_K {k:g}" if scaled and k != 1.0 else ""
                out.append(
                    f"the vehicle's {param} is {value:g}{times}, but "
                    f"[controller.attitude_feedforward] {key}[{axis}] is {configured:g}: the "
                    "offsets would not make the torque they are for; set the config to the "
                    "vehicle's gains (or remove the section)"
                )
    return out

"""Whether the vehicle and its arm can carry a payload: the hover thrust and the joints'
gravity torques it needs, against their limits (pure, no clock).

At the end of the grasp the estimator has seen the payload's weight (link 2's mass m2,
paper eq. theta) but not yet where along link 2 it sits (that takes the excitation). The
check takes the payload as a point mass ``m2 - m2_empty`` at the grasp point (where the
companion's jaws hold it) on the empty link 2, and asks:

- **thrust**: the relative thrust (PX4's, a fraction of the vehicle's maximum: the thrust
  model's over the calibrated thrust scale s) to hover with it, and the one the lift
  commands (an object whose weight comes on only as it leaves the ground shows there
  first, before the estimator has learnt it), stay at most ``[flight] max_hover_thrust``:
  above it PX4 is left too little for attitude control and the climb;
- **servos**: at each pose the arm takes with it (arm down, the excitation's two extremes)
  each joint's gravity torque (the model's G, eq. tau2's gravity vector) stays at most
  ``[flight] max_joint_torque_fraction`` of the joint's ``torque_max_n_m``.

The mission asks from the end of the grasp through the lift's first
:data:`~companion.mission.pickup.WEIGH_HEIGHT_M` (an object whose weight comes onto the
arm only as it leaves the ground is weighed there); :class:`AuthorityWatch` refuses a
payload found beyond either for
:data:`PERSIST_S` (``beyond_authority``): the mission opens the gripper, so the object is
let go where it lay or from at most that height, and flies home
(:mod:`companion.mission.failsafe`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from companion.config import CompanionConfig
from companion.coordinates import ETA1, ETA2, N_Q, Z
from companion.model import ManipulatorModel

__all__ = [
    "PERSIST_S",
    "AuthorityLimits",
    "AuthorityWatch",
    "lift_thrust_reason",
    "payload_authority",
]

PERSIST_S = 0.3
"""How long the estimate must stay beyond a limit before the payload is refused [s]: a
grasp's transient is not a payload."""


@dataclass(frozen=True)
class AuthorityLimits:
    """What the vehicle and the servos may be asked for with a payload.

    Attributes
    ----------
    max_hover_thrust
        Largest relative thrust (PX4's, 0-1) to hover with the payload.
    joint_torque_max_n_m
        Per joint (eta1, eta2), the largest torque a command may ask for [N m].
    max_joint_torque_fraction
        Fraction of it the payload's gravity torque may take.
    """

    max_hover_thrust: float
    joint_torque_max_n_m: tuple[float, float]
    max_joint_torque_fraction: float

    @classmethod
    def from_config(cls, config: CompanionConfig) -> AuthorityLimits:
        """From ``[flight]`` and the joints of ``[arm_bus]`` (unlimited without a bus)."""
        bus = config.arm_bus
        limits = (np.inf, np.inf)
        if bus is not None and len(bus.joints) >= 2:
            limits = (bus.joints[0].torque_max_n_m, bus.joints[1].torque_max_n_m)
        return cls(config.flight.max_hover_thrust, limits, config.flight.max_joint_torque_fraction)


def payload_authority(
    model: ManipulatorModel,
    max_thrust_n: float,
    limits: AuthorityLimits,
    m2_kg: float,
    empty_theta: Sequence[float],
    grasp_point_m: float,
    thrust_scale: float,
    poses: Sequence[tuple[float, float]],
) -> str | None:
    """Why a payload making link 2's mass ``m2_kg`` [kg] cannot be carried (one line), or
    None. ``empty_theta``: the empty link 2's (m2, m3, m4); the payload is a point mass at
    ``grasp_point_m`` [m] along link 2; ``max_thrust_n``: the thrust model's collective
    thrust at relative thrust 1 [N], of which the vehicle makes ``thrust_scale`` times;
    ``poses``: the (eta1, eta2) [rad] the arm takes with it."""
    payload_kg = max(m2_kg - float(empty_theta[0]), 0.0)
    theta = np.array(
        [
            float(empty_theta[0]) + payload_kg,
            float(empty_theta[1]) + payload_kg * grasp_point_m,
            float(empty_theta[2]) + payload_kg * grasp_point_m**2,
        ]
    )
    q = np.zeros(N_Q)
    weight_n = float(model.gravity(q, theta)[Z])
    hover = weight_n / (thrust_scale * max_thrust_n)
    if hover > limits.max_hover_thrust:
        return _thrust_reason(f"hovering with the payload (m2 = {m2_kg:.3f} kg)", hover, limits)
    worst = (0.0, 0.0)
    for eta1, eta2 in poses:
        q[ETA1], q[ETA2] = eta1, eta2
        g = model.gravity(q, theta)
        worst = (max(worst[0], abs(float(g[ETA1]))), max(worst[1], abs(float(g[ETA2]))))
    joints = zip(("eta1", "eta2"), worst, limits.joint_torque_max_n_m, strict=True)
    for name, torque, limit in joints:
        allowed = limits.max_joint_torque_fraction * limit
        if torque > allowed:
            return (
                f"servo torque beyond the limit: holding the payload (m2 = {m2_kg:.3f} kg at "
                f"{grasp_point_m:.3f} m) through the mission's arm poses takes {torque:.2f} N m "
                f"at joint {name}, more than {allowed:.2f} N m "
                f"({100 * limits.max_joint_torque_fraction:.0f} % of its {limit:g} N m)"
            )
    return None


def lift_thrust_reason(thrust_relative: float, limits: AuthorityLimits) -> str | None:
    """Why the lift's commanded relative thrust (PX4's, 0-1) is beyond the hover limit
    (one line), or None."""
    if not thrust_relative > limits.max_hover_thrust:
        return None
    return _thrust_reason("lifting the payload", thrust_relative, limits)


def _thrust_reason(what: str, relative: float, limits: AuthorityLimits) -> str:
    """The one line of a relative thrust beyond the hover limit."""
    return (
        f"thrust margin exceeded: {what} takes {100 * relative:.1f} % of the vehicle's "
        f"maximum thrust, more than the {100 * limits.max_hover_thrust:.0f} % allowed "
        "([flight] max_hover_thrust)"
    )


@dataclass
class AuthorityWatch:
    """The check of one pickup over vehicle time: a reason that has held for
    :data:`PERSIST_S` refuses the payload."""

    _since_s: float = math.nan

    def update(self, t_s: float, why: str | None) -> str | None:
        """This cycle's reason at vehicle time ``t_s`` [s] (None: within the limits); the
        reason once it has held long enough, else None."""
        if why is None:
            self._since_s = math.nan
            return None
        if math.isnan(self._since_s):
            self._since_s = t_s
        return why if t_s - self._since_s >= PERSIST_S else None

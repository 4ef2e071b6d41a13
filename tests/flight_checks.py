"""Checks shared by the pickup flights (imitation, PX4 in the loop, PX4 SIH)."""

from __future__ import annotations

import math

import numpy as np

MISSION_PHASES = [
    "to_object", "descend", "grasp", "lift", "excite", "to_place",
    "lower", "release", "climb", "to_home", "done",
]  # fmt: skip
"""The pickup's phases in order (what the flight log's ``phase`` column holds in OFFBOARD)."""
CARRY_PHASES = ("lift", "to_place", "lower")
"""From lift to place, the excitation left out (where the carry RMS of the adaptive and the
non-adaptive controller are compared)."""
CARRY_JOINT_RATE_RMS_BOUND_RAD_S = 0.3
"""Joint rate RMS over :data:`CARRY_PHASES` the arm must keep, each joint: it holds still
while carrying (0.01-0.05 rad/s measured under the imitation and PX4 in the loop); the
elbow mode oscillating against a stale joint state (in CI) gave 2-5 rad/s."""
CARRY_RMS_BOUND_M = 0.04
"""Carry RMS the adaptive controller must keep: 1.5-2.7 cm measured under the imitation and
PX4 in the loop; the non-adaptive one carries the object about 6.5 cm low (6.6 cm RMS)."""


def assert_calm_flight(c: dict[str, np.ndarray]) -> None:
    """The flight-acceptance figures of a flight log's columns ``c``: no tilt saturation
    in OFFBOARD, tilt below 15 deg outside the excitation, the handover's tilt change below
    5 deg over its first 2 s, position RMS outside the excitation below 10 cm against the
    vehicle's own estimate; and the arm still over the carry, if there was one
    (:data:`CARRY_JOINT_RATE_RMS_BOUND_RAD_S`)."""
    flown = np.isin(c["phase"], MISSION_PHASES)
    tilt_deg = np.degrees(np.hypot(c["q_phi_rad"], c["q_theta_rad"]))
    assert not np.any(c["sp_tilt_saturated"][flown] == 1.0)
    calm = flown & (c["phase"] != "excite")
    assert tilt_deg[calm].max() < 15.0
    first = np.flatnonzero(flown)[0]
    window = flown & (c["t_vehicle_s"] <= c["t_vehicle_s"][first] + 2.0)
    assert np.max(np.abs(tilt_deg[window] - tilt_deg[first])) < 5.0
    assert position_rms_m(c, calm) < 0.10
    carry = np.isin(c["phase"], CARRY_PHASES)
    if carry.any():
        for joint in ("eta1", "eta2"):
            rate = c[f"qdot_{joint}_rad_s"][carry]
            assert math.sqrt(float(np.mean(rate**2))) < CARRY_JOINT_RATE_RMS_BOUND_RAD_S, joint


def position_rms_m(c: dict[str, np.ndarray], rows: np.ndarray) -> float:
    """Position RMS [m] against the plan over the ``rows`` (a mask) of a flight log's
    columns ``c``."""
    error = np.stack([c[f"q_{a}_m"][rows] - c[f"qd_{a}_m"][rows] for a in "xyz"])
    return math.sqrt(float(np.mean(np.sum(error**2, axis=0))))


def carry_rms_m(c: dict[str, np.ndarray]) -> float:
    """Position RMS [m] against the plan over :data:`CARRY_PHASES` of a flight log's
    columns ``c``."""
    return position_rms_m(c, np.isin(c["phase"], CARRY_PHASES))

"""A payload beyond the vehicle's or the servos' authority: the check at the end of the
grasp (companion.mission.authority), against figures worked out by hand."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from companion.config import ConfigError, load_config
from companion.mission.authority import (
    PERSIST_S,
    AuthorityLimits,
    AuthorityWatch,
    payload_authority,
)
from companion.mission.pickup import PickupMission, PickupPlan
from companion.model import ManipulatorModel

CONFIG = load_config("configs/sitl_pickup.toml")
MODEL = ManipulatorModel.from_config(CONFIG)
EMPTY = CONFIG.nominal_theta.as_tuple()
MAX_THRUST_N = 6 * CONFIG.vehicle.rotors.max_thrust_per_rotor_n  # 36 N
G = CONFIG.environment.gravity_m_s2
BASE_KG = CONFIG.vehicle.mass_kg + CONFIG.arm.link1.mass_kg  # 1.1 kg; link 2 0.12 kg
DOWN = (-0.5 * math.pi, 0.0)


def check(m2_kg: float, limits: AuthorityLimits, scale: float = 1.0, poses=(DOWN,), lc=0.15):
    return payload_authority(MODEL, MAX_THRUST_N, limits, m2_kg, EMPTY, lc, scale, poses)


def test_the_limits_come_from_flight_and_the_joints():
    limits = AuthorityLimits.from_config(CONFIG)
    assert limits == AuthorityLimits(0.7, (4.1, 4.1), 0.8)


def test_a_payload_needing_more_than_the_hover_thrust_allowed_is_refused():
    """Hover at 70 % of 36 N holds 25.2 N: 2.569 kg in all, m2 up to 1.469 kg."""
    limits = AuthorityLimits(0.7, (math.inf, math.inf), 0.8)
    m2_limit = 0.7 * MAX_THRUST_N / G - BASE_KG
    assert check(m2_limit - 0.01, limits) is None
    why = check(m2_limit + 0.01, limits)
    assert why is not None and why.startswith("thrust margin exceeded")
    assert "70.3 % of the vehicle's maximum thrust" in why and "[flight] max_hover_thrust" in why
    # A vehicle whose thrust is 10 % weaker than its model's carries 10 % less.
    assert check(0.9 * (m2_limit + BASE_KG) - BASE_KG + 0.01, limits, scale=0.9) is not None
    assert check(0.9 * (m2_limit + BASE_KG) - BASE_KG - 0.01, limits, scale=0.9) is None


def test_a_payload_needing_more_servo_torque_than_allowed_is_refused():
    """Arm straight down, gravity pulls along the links: no torque. At eta1 = -pi/2 + 0.5,
    eta2 = 0.4 the shoulder holds link 1 (0.1 kg at its CoM), link 2 and the payload
    (1 kg at 0.15 m): the torque is g times their masses' horizontal lever."""
    limits = AuthorityLimits(1.0, (4.1, 4.1), 0.5)
    assert check(1.12, limits) is None  # arm down: nothing on the joints
    swing = (-0.5 * math.pi + 0.5, 0.4)
    arm = CONFIG.arm
    l1, c1, c2 = arm.link1.length_m, arm.link1.com_m, arm.link2.com_m
    s1, s12 = math.sin(0.5), math.sin(0.9)
    shoulder = G * (
        arm.link1.mass_kg * c1 * s1
        + arm.link2.mass_kg * (l1 * s1 + c2 * s12)
        + 1.0 * (l1 * s1 + 0.15 * s12)
    )
    elbow = G * (arm.link2.mass_kg * c2 + 1.0 * 0.15) * s12
    tight = AuthorityLimits(1.0, (shoulder / 0.5 + 0.01, elbow / 0.5 + 0.01), 0.5)
    assert check(1.12, tight, poses=(DOWN, swing)) is None
    short = AuthorityLimits(1.0, (shoulder / 0.5 - 0.01, 10.0), 0.5)
    why = check(1.12, short, poses=(DOWN, swing))
    assert why is not None and why.startswith("servo torque beyond the limit")
    assert f"takes {shoulder:.2f} N m at joint eta1" in why
    elbow_short = AuthorityLimits(1.0, (10.0, elbow / 0.5 - 0.01), 0.5)
    assert "at joint eta2" in check(1.12, elbow_short, poses=(DOWN, swing))


def test_an_estimate_below_the_empty_link_adds_no_payload():
    limits = AuthorityLimits(0.34, (0.1, 0.1), 0.5)  # the empty vehicle hovers at 0.3325
    assert check(0.05, limits) is None


def test_the_mission_knows_the_poses_it_loads_the_arm_in():
    plan = PickupPlan(
        home_m=(0.0, 0.0), payload_at_m=(1.0, 0.0, 0.05), place_at_m=(-1.0, 0.5, 0.05)
    )
    mission = PickupMission(plan, CONFIG)
    assert mission.grasp_point_m == pytest.approx(CONFIG.arm.link2.length_m - 0.02)
    down, up, back = mission.loaded_poses()
    assert down == DOWN
    assert up == pytest.approx((-0.5 * math.pi + plan.excite_eta1_rad, plan.excite_eta2_rad))
    assert back == pytest.approx((-0.5 * math.pi - plan.excite_eta1_rad, -plan.excite_eta2_rad))
    # a payload four times the one the swing is for swings half as far
    halved = PickupMission(replace(plan, excite_payload_kg=0.25), CONFIG)
    _, up, back = halved.loaded_poses(1.0)
    assert up == pytest.approx(
        (-0.5 * math.pi + 0.5 * plan.excite_eta1_rad, 0.5 * plan.excite_eta2_rad)
    )
    assert halved.loaded_poses(0.2) == mission.loaded_poses()


@pytest.mark.parametrize(
    ("key", "value"), [("max_hover_thrust", 1.2), ("max_joint_torque_fraction", 0.0)]
)
def test_flight_limits_out_of_range_are_refused(tmp_path, key, value):
    text = (
        open("configs/sitl_pickup.toml").read().replace("[flight]", f"[flight]\n{key} = {value}", 1)
    )
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=f"flight.{key}"):
        load_config(path)


def test_a_reason_refuses_only_once_it_has_held():
    """A grasp's transient (a reason for less than PERSIST_S) is not a payload."""
    watch = AuthorityWatch()
    assert watch.update(10.0, "too heavy") is None
    assert watch.update(10.0 + PERSIST_S / 2, "too heavy") is None
    assert watch.update(10.0 + PERSIST_S / 2 + 0.01, None) is None  # gone: starts again
    assert watch.update(11.0, "too heavy") is None
    assert watch.update(11.0 + PERSIST_S, "too heavy") == "too heavy"

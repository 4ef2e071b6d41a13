"""companion.calibration.config_edit: calibrated values written into a config TOML, the rest
untouched."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from companion.calibration.config_edit import with_joint_values
from companion.config import ConfigError, arm_bus_configs, parse_config

CONFIG = Path(__file__).parent.parent / "configs" / "sitl_pickup.toml"
NOTE = "companion arm calibrate, 2026-12-02"


def test_values_change_in_place_and_every_other_line_stays() -> None:
    text = CONFIG.read_text()
    edited = with_joint_values(
        text,
        {
            "eta2": {
                "torque_constant_n_m_per_a": 1.9583,
                "viscous_friction_n_m_s_per_rad": 0.0201,
                "coulomb_friction_n_m": 0.004,
            }
        },
        NOTE,
    )
    joints, _ = arm_bus_configs(parse_config(tomllib.loads(edited)).arm_bus)
    assert joints[1].torque_constant_n_m_per_a == 1.9583
    assert joints[1].viscous_friction_n_m_s_per_rad == 0.0201
    assert joints[1].coulomb_friction_n_m == 0.004
    assert joints[0] == arm_bus_configs(parse_config(tomllib.loads(text)).arm_bus)[0][0]
    old, new = text.splitlines(), edited.splitlines()
    assert len(new) == len(old) + 1
    (at,) = [i for i, line in enumerate(new) if line.startswith("coulomb_friction_n_m")]
    added, rest = new[at], new[:at] + new[at + 1 :]
    changed = [(before, after) for before, after in zip(old, rest, strict=True) if before != after]
    assert [(b.split(" = ")[0], a.split(" = ")[1].split()[0]) for b, a in changed] == [
        ("torque_constant_n_m_per_a", "1.9583"),
        ("viscous_friction_n_m_s_per_rad", "0.0201"),
    ]
    for before, after in changed:  # each keeps its comment, in its column
        assert after.index("#") == before.index("#")
        assert after.split("#", 1)[1] == before.split("#", 1)[1]
    assert added.startswith("coulomb_friction_n_m = 0.004 ")
    assert added.endswith(f"# {NOTE}") and added.index("#") == changed[0][0].index("#")
    eta2 = new.index('name = "eta2"')
    gripper = next(i for i, line in enumerate(new) if line.startswith("[arm_bus.gripper]"))
    assert eta2 < at < gripper  # at the end of eta2's table


def test_the_calibrated_flag_is_written_as_a_toml_boolean() -> None:
    text = CONFIG.read_text()
    before = parse_config(tomllib.loads(text)).arm_bus
    assert before is not None and not any(j.torque_calibrated for j in before.joints)
    edited = with_joint_values(text, {"eta1": {"torque_calibrated": True}}, NOTE)
    assert f"torque_calibrated = true # {NOTE}" in " ".join(edited.split())
    after = parse_config(tomllib.loads(edited)).arm_bus
    assert after is not None and [j.torque_calibrated for j in after.joints] == [True, False]


def test_an_unknown_joint_is_refused() -> None:
    with pytest.raises(ConfigError, match="no joint named 'wrist'"):
        with_joint_values(CONFIG.read_text(), {"wrist": {"coulomb_friction_n_m": 0.01}}, NOTE)


def test_a_value_the_config_would_refuse_is_not_returned() -> None:
    with pytest.raises(ConfigError) as info:
        with_joint_values(CONFIG.read_text(), {"eta1": {"coulomb_friction_n_m": -0.01}}, NOTE)
    assert info.value.key == "arm_bus.joints[0].coulomb_friction_n_m"


def test_a_file_without_an_arm_bus_has_no_joint_to_write() -> None:
    text = (CONFIG.parent / "paper_sim.toml").read_text()
    with pytest.raises(ConfigError, match="no joint named 'eta1'"):
        with_joint_values(text, {"eta1": {"coulomb_friction_n_m": 0.01}}, NOTE)

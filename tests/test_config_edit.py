"""companion.config_edit: calibrated values written into a config TOML, the rest untouched."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from companion.config import ConfigError, arm_bus_configs, parse_config
from companion.config_edit import with_joint_values

CONFIG = Path(__file__).parent.parent / "configs" / "sitl_pickup.toml"
NOTE = "companion arm calibrate, 2026-12-02"


def test_values_change_in_place_and_every_other_line_stays() -> None:
    text = CONFIG.read_text()
    edited = with_joint_values(
        text,
        {"eta2": {"torque_constant_n_m_per_a": 1.9583, "viscous_friction_n_m_s_per_rad": 0.0201}},
        NOTE,
    )
    joints, _ = arm_bus_configs(parse_config(tomllib.loads(edited)).arm_bus)
    assert joints[1].torque_constant_n_m_per_a == 1.9583
    assert joints[1].viscous_friction_n_m_s_per_rad == 0.0201
    assert joints[0] == arm_bus_configs(parse_config(tomllib.loads(text)).arm_bus)[0][0]
    old, new = text.splitlines(), edited.splitlines()
    changed = [line for line in old if line not in new]
    assert len(changed) == 1 and changed[0].startswith("torque_constant_n_m_per_a = 1.78")
    kept = next(line for line in new if line.startswith("torque_constant_n_m_per_a = 1.9583"))
    assert kept.index("#") == changed[0].index("#")  # its comment, in its column
    assert kept.split("#", 1)[1] == changed[0].split("#", 1)[1]
    added = [line for line in new if line not in old]
    assert added[1].startswith("viscous_friction_n_m_s_per_rad = 0.0201 ")
    assert added[1].endswith(f"# {NOTE}") and added[1].index("#") == changed[0].index("#")
    eta2 = new.index('name = "eta2"')
    gripper = next(i for i, line in enumerate(new) if line.startswith("[arm_bus.gripper]"))
    assert eta2 < new.index(added[1]) < gripper  # at the end of eta2's table
    assert len(new) == len(old) + 1


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

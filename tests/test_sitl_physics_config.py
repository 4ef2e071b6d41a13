"""The config keys the truth plant adds: [vehicle.rotors], [plant], [plant.attitude_control]."""

import math
import tomllib
from pathlib import Path

import pytest

from companion.config import ConfigError
from sitl.scenario import load_scenario, parse_scenario

CONFIGS = Path(__file__).parent.parent / "configs"


def data(name: str = "paper_sim.toml") -> dict:
    return tomllib.loads((CONFIGS / name).read_text())


def changed(dotted: str, value=None, delete: bool = False) -> dict:
    doc = data()
    *parents, leaf = dotted.split(".")
    node = doc
    for part in parents:
        node = node[part]
    if delete:
        del node[leaf]
    else:
        node[leaf] = value
    return doc


@pytest.mark.parametrize("name", ["paper_sim.toml", "experiment_arm.toml"])
def test_shipped_configs_carry_the_plant_keys(name) -> None:
    cfg = load_scenario(CONFIGS / name)
    assert cfg.plant.rate_hz >= 1000.0
    assert cfg.plant.integrator == "semi_implicit_euler"
    assert cfg.plant.servo_torque_limit_n_m == 4.1
    assert cfg.plant.attitude_control.attitude_p == (4.0, 4.0, 2.8)  # PX4 main
    assert cfg.plant.attitude_control.rate_p == (0.15, 0.15, 0.2)
    assert cfg.plant.attitude_control.rate_i == (0.2, 0.2, 0.1)
    assert cfg.plant.attitude_control.rate_d == (0.003, 0.003, 0.0)
    rates = cfg.plant.attitude_control.rate_max_rad_s
    assert [math.degrees(r) for r in rates] == pytest.approx([220.0, 220.0, 200.0])
    assert cfg.vehicle.rotors.max_thrust_per_rotor_n == 6.0


def test_every_new_value_has_a_source_note() -> None:
    """Each key line of the new sections ends in a comment naming where it comes from."""
    for name in ("paper_sim.toml", "experiment_arm.toml"):
        section = None
        for line in (CONFIGS / name).read_text().splitlines():
            if line.startswith("["):
                section = line.split("]")[0].strip("[")
                continue
            if section in ("vehicle.rotors", "plant", "plant.attitude_control") and "=" in line:
                comment = line.partition("#")[2].strip()
                source = comment.split(":")[0]
                assert source in ("assumed", "datasheet", "PX4 default") or source.startswith(
                    "PX4 main default"
                ), line


@pytest.mark.parametrize(
    ("doc", "key", "reason"),
    [
        (changed("plant.rate_hz", 500.0), "plant.rate_hz", "greater than or equal to 1000"),
        (changed("plant.rate_hz", "1000"), "plant.rate_hz", "valid number"),
        (changed("plant.integrator", "rk2"), "plant.integrator", "'semi_implicit_euler' or 'rk4'"),
        (changed("plant.thrust_mismatch", 0.0), "plant.thrust_mismatch", "greater than 0"),
        (changed("plant.servo_torque_limit_n_m", -4.1), "plant.servo_torque_limit_n_m", "greater"),
        (changed("plant.linear_drag_n_s_m", [0.1, 0.1]), "plant.linear_drag_n_s_m", "at least 3"),
        (changed("plant.mass_kg", 1.0), "plant.mass_kg", "unknown key"),
        (changed("plant", delete=True), "plant", "missing key"),
        (
            changed("plant.attitude_control.mc_roll_p", 6.5),
            "plant.attitude_control.mc_roll_p",
            "unknown key",
        ),
        (
            changed("plant.attitude_control.yaw_weight", 1.5),
            "plant.attitude_control.yaw_weight",
            "less than or equal to 1",
        ),
        (
            changed("plant.attitude_control.rate_p", [0.15, -0.1, 0.2]),
            "plant.attitude_control.rate_p[1]",
            "greater than or equal to 0",
        ),
        (changed("vehicle.rotors.thr_mdl_fac", 1.5), "vehicle.rotors.thr_mdl_fac", "less than"),
        (changed("vehicle.rotors", delete=True), "vehicle.rotors", "missing key"),
        (
            changed("vehicle.rotors.motor_time_constant_s", 0.0),
            "vehicle.rotors.motor_time_constant_s",
            "greater than 0",
        ),
    ],
)
def test_bad_plant_keys_name_file_key_and_reason(doc, key, reason) -> None:
    with pytest.raises(ConfigError) as info:
        parse_scenario(doc, "cfg.toml")
    assert info.value.key == key
    assert reason in info.value.reason
    assert str(info.value).startswith(f"cfg.toml: {key}: ")


def test_bad_plant_key_in_a_file(tmp_path) -> None:
    text = (
        (CONFIGS / "experiment_arm.toml").read_text().replace("rate_hz = 1000.0", "rate_hz = 250.0")
    )
    path = tmp_path / "slow.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"slow\.toml: plant\.rate_hz: .*1000"):
        load_scenario(path)

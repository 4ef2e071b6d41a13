"""companion.config: the optional ``world`` section of the SITL."""

import tomllib
from pathlib import Path

import pytest

from companion.config import ConfigError
from sitl.scenario import load_scenario, parse_scenario

PICKUP = Path(__file__).parent.parent / "configs" / "sitl_pickup.toml"


def data() -> dict:
    return tomllib.loads(PICKUP.read_text())


def test_pickup_config_places_an_object_unknown_to_the_companion():
    cfg = load_scenario(PICKUP)
    assert cfg.world is not None
    assert cfg.world.payload_position_m == (1.5, 1.0, 0.05)
    assert cfg.payload.mass_kg == 0.25
    # The companion starts from the empty link 2: its initial estimate is not the truth.
    assert cfg.estimator.initial_theta.m2_kg < cfg.true_theta.m2_kg - 0.2


def test_unknown_world_key_gets_a_hint():
    raw = data()
    raw["world"]["landing_gear_hieght_m"] = raw["world"].pop("landing_gear_height_m")
    with pytest.raises(ConfigError) as info:
        parse_scenario(raw, "x.toml")
    assert "world.landing_gear_hieght_m" in str(info.value)
    assert "landing_gear_height_m" in str(info.value)


def test_object_below_ground_is_rejected():
    raw = data()
    raw["world"]["payload_position_m"] = [1.0, 1.0, -0.1]
    with pytest.raises(ConfigError, match="below the ground"):
        parse_scenario(raw, "x.toml")


@pytest.mark.parametrize(("value", "words"), [(0.18, "beyond link 2"), (0.0, "greater than 0")])
def test_jaws_beyond_link_2_or_not_positive_are_rejected(value, words):
    raw = data()
    raw["world"]["jaw_point_m"] = value
    with pytest.raises(ConfigError, match=words) as info:
        parse_scenario(raw, "x.toml")
    assert "world.jaw_point_m" in str(info.value)


def test_autopilot_params_must_be_numbers():
    raw = data()
    raw["world"]["autopilot_params"] = {"COM_OF_LOSS_T": "1.0"}
    with pytest.raises(ConfigError, match="autopilot_params"):
        parse_scenario(raw, "x.toml")


def test_world_section_is_optional():
    raw = data()
    del raw["world"]
    assert parse_scenario(raw, "x.toml").world is None

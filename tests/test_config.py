"""companion.config: loading, validation and the CLI's handling of bad files."""

import tomllib
from pathlib import Path

import pydantic
import pytest

from companion.config import (
    SIMULATOR_SECTIONS,
    CompanionConfig,
    ConfigError,
    load_config,
    parse_config,
)
from sitl.scenario import load_scenario, parse_scenario

CONFIGS = Path(__file__).parent.parent / "configs"
PAPER = CONFIGS / "paper_sim.toml"


def paper_data() -> dict:
    return tomllib.loads(PAPER.read_text())


def with_value(dotted: str, value) -> dict:
    data = paper_data()
    *parents, leaf = dotted.split(".")
    node = data
    for part in parents:
        node = node[part]
    node[leaf] = value
    return data


def without(dotted: str) -> dict:
    data = paper_data()
    *parents, leaf = dotted.split(".")
    node = data
    for part in parents:
        node = node[part]
    del node[leaf]
    return data


@pytest.mark.parametrize("name", ["paper_sim.toml", "experiment_arm.toml"])
def test_shipped_configs_load(name: str) -> None:
    cfg = load_scenario(CONFIGS / name)
    assert cfg.name == name.removesuffix(".toml")


def test_paper_truth_and_nominal() -> None:
    cfg = load_scenario(PAPER)
    assert cfg.true_theta.as_tuple() == pytest.approx((0.5, 0.08, 0.0128))
    assert cfg.true_theta.lc_m == pytest.approx(0.16)
    assert cfg.nominal_theta.m2_kg == pytest.approx(0.1)
    assert cfg.controller.lambda_ == (1.0, 1.0, 5.0, 1.0, 1.0, 1.0, 0.2, 0.2)


def test_experiment_arm_matches_paper_section_v() -> None:
    cfg = load_scenario(CONFIGS / "experiment_arm.toml")
    assert cfg.arm.link1.length_m == 0.135
    assert cfg.arm.link2.length_m == 0.17
    assert cfg.arm.link1.mass_kg + cfg.arm.link2.mass_kg == pytest.approx(0.22)
    assert cfg.true_theta.m2_kg == pytest.approx(0.238)
    assert cfg.true_theta.lc_m == pytest.approx(0.09, abs=0.005)


def test_objects_are_frozen() -> None:
    cfg = load_scenario(PAPER)
    with pytest.raises(pydantic.ValidationError):
        cfg.vehicle.mass_kg = 2.0  # type: ignore[misc]


@pytest.mark.parametrize(
    ("data", "key", "reason"),
    [
        (with_value("vehicle.mas_kg", 1.0), "vehicle.mas_kg", "did you mean 'mass_kg'"),
        (with_value("arm.link2.armature", 0.01), "arm.link2.armature", "unknown key"),
        (without("vehicle.mass_kg"), "vehicle.mass_kg", "missing key"),
        (without("controller"), "controller", "missing key"),
        (with_value("vehicle.mass_kg", "1.0"), "vehicle.mass_kg", "valid number"),
        (with_value("vehicle.mass_kg", True), "vehicle.mass_kg", "valid number"),
        (with_value("vehicle.mass_kg", -1.0), "vehicle.mass_kg", "greater than 0"),
        (
            with_value("vehicle.inertia_kg_m2", [0.01, -0.01, 0.02]),
            "vehicle.inertia_kg_m2[1]",
            "greater than 0",
        ),
        (with_value("vehicle.inertia_kg_m2", [0.01, 0.01]), "vehicle.inertia_kg_m2", "at least 3"),
        (
            with_value("arm.link1.inertia_about_com_kg_m2", -1e-4),
            "arm.link1.inertia_about_com_kg_m2",
            "greater than or equal to 0",
        ),
        (with_value("payload.mass_kg", -0.4), "payload.mass_kg", "greater than or equal to 0"),
        (with_value("arm.link1.com_m", 0.3), "arm.link1.com_m", "beyond the link length"),
        (with_value("payload.position_m", 0.25), "payload.position_m", "beyond link 2"),
        (
            with_value("estimator.initial_theta.m3_kg_m", 0.03),
            "estimator.initial_theta",
            "outside [0, l2]",
        ),
        (
            with_value("estimator.initial_theta.m4_kg_m2", 1e-6),
            "estimator.initial_theta",
            "m4 = 1e-06 kg m^2 < m3^2/m2",
        ),
        (
            with_value("controller.k", [4.5, 4.5, 7.5, 8.0, 8.0, 0.0, 1.4, 1.4]),
            "controller.k[5]",
            "greater than 0",
        ),
        (with_value("estimator.k_star", [20.0] * 7), "estimator.k_star", "at least 8"),
        (with_value("estimator.gamma", [0.2, -0.1, 0.1]), "estimator.gamma[1]", "greater than 0"),
        (
            with_value("environment.gravity_m_s2", float("nan")),
            "environment.gravity_m_s2",
            "finite",
        ),
        (with_value("trajectory.kind", "circle"), "trajectory.kind", "paper_sinusoid"),
    ],
)
def test_rejects_with_file_key_and_reason(data: dict, key: str, reason: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_scenario(data, "cfg.toml")
    err = info.value
    assert err.path == "cfg.toml"
    assert err.key == key
    assert reason in err.reason
    assert str(err).startswith(f"cfg.toml: {key}: ")


def test_reports_every_problem_unknown_keys_first() -> None:
    data = without("vehicle.mass_kg")
    data["vehicle"]["mas_kg"] = 1.0
    data["payload"]["mass_kg"] = -1.0
    with pytest.raises(ConfigError) as info:
        parse_scenario(data, "cfg.toml")
    keys = [key for key, _ in info.value.problems]
    assert keys[0] == "vehicle.mas_kg"
    assert set(keys) == {"vehicle.mas_kg", "vehicle.mass_kg", "payload.mass_kg"}


def test_point_mass_initial_theta_is_consistent() -> None:
    """m4 = m3^2/m2 exactly (the paper's initial estimates) must not be rejected by rounding."""
    data = with_value("estimator.initial_theta.m4_kg_m2", (1.0e-3) ** 2 / 0.1)
    assert parse_scenario(data).estimator.initial_theta.m4_kg_m2 == pytest.approx(1e-5)


def test_file_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read file"):
        load_scenario(tmp_path / "absent.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[vehicle\nmass_kg = 1")
    with pytest.raises(ConfigError, match="invalid TOML") as info:
        load_scenario(broken)
    assert info.value.path == str(broken)


def test_cli_check_accepts_good_file(run_cli, run_sitl) -> None:
    companion = run_cli("check", str(PAPER))
    assert companion.returncode == 0, companion.stderr
    assert "0.1, 0.016, 0.00256, 0.16" in companion.stdout  # the empty link 2 only
    assert "with payload" not in companion.stdout
    whole = run_sitl("check", str(PAPER))
    assert whole.returncode == 0, whole.stderr
    assert "0.5, 0.08, 0.0128, 0.16" in whole.stdout  # with the payload: the truth


def test_the_companions_types_cannot_hold_the_truth() -> None:
    """The same file, two owners: the companion's loader skips the simulator's sections
    (payload, plant, world, simulation, trajectory), and its type has no field for them."""
    beliefs = load_config(PAPER)
    assert not any(hasattr(beliefs, name) for name in SIMULATOR_SECTIONS)
    assert not any(name in CompanionConfig.model_fields for name in SIMULATOR_SECTIONS)
    scenario = load_scenario(PAPER)
    assert scenario.beliefs == beliefs and type(scenario.beliefs) is CompanionConfig
    assert scenario.true_theta.m2_kg == pytest.approx(0.5)


def test_an_unknown_top_level_section_is_refused_by_both_owners() -> None:
    data = tomllib.loads(PAPER.read_text())
    data["paylod"] = data.pop("payload")
    with pytest.raises(ConfigError, match="paylod: unknown key"):
        parse_config(data)
    with pytest.raises(ConfigError, match="paylod: unknown key"):
        parse_scenario(data)


def test_cli_bad_config_exits_2_without_traceback(run_cli, tmp_path: Path) -> None:
    bad = tmp_path / "typo.toml"
    bad.write_text(PAPER.read_text().replace("mass_kg = 1.0 ", "mas_kg = 1.0 "))
    result = run_cli("check", str(bad))
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert f"{bad}: vehicle.mas_kg: unknown key; did you mean 'mass_kg'?" in result.stderr


def test_cli_missing_file_exits_2(run_cli, tmp_path: Path) -> None:
    result = run_cli("check", str(tmp_path / "nope.toml"))
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert "cannot read file" in result.stderr


def test_a_key_with_a_line_break_is_named_on_one_line():
    """An unknown key holding a newline or a carriage return is quoted with escapes, so
    that each problem stays one line."""
    data = tomllib.loads((CONFIGS / "sitl_pickup.toml").read_text())
    data["\r"] = 0.0
    data["flight"]["a\nb"] = 1
    with pytest.raises(ConfigError) as caught:
        parse_config(data, "x.toml")
    assert str(caught.value).splitlines() == [
        "x.toml: flight.'a\\nb': unknown key",
        "x.toml: '\\r': unknown key",
    ]

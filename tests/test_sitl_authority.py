"""sitl.offline.authority and the sitl command line."""

from pathlib import Path

import pytest

from sitl.offline.authority import hover_authority
from sitl.physics.rotors import thrust_curve
from sitl.scenario import load_scenario

CONFIGS = Path(__file__).parent.parent / "configs"


def test_hover_command_produces_the_weight() -> None:
    cfg = load_scenario(CONFIGS / "paper_sim.toml")
    a = hover_authority(cfg, payload_attached=True)
    assert a.mass_kg == pytest.approx(1.6)
    rotors = cfg.vehicle.rotors
    total = 6 * rotors.max_thrust_per_rotor_n * thrust_curve(a.hover_command, rotors.thr_mdl_fac)
    assert total == pytest.approx(a.hover_thrust_n)


def test_authority_is_positive_and_ordered() -> None:
    cfg = load_scenario(CONFIGS / "paper_sim.toml")
    empty, loaded = hover_authority(cfg, False), hover_authority(cfg, True)
    for a in (empty, loaded):
        for unsat, best in zip(a.unsaturated_torque_n_m, a.max_torque_n_m, strict=True):
            assert 0.0 < unsat <= best + 1e-12
        # pitch arms of a hexa-X (rotors at +-30 deg) are longer than its roll arms
        assert a.max_torque_n_m[1] > a.max_torque_n_m[0]
    # a heavier hover leaves more room below the hover command on this curve
    assert loaded.unsaturated_torque_n_m[1] > empty.unsaturated_torque_n_m[1]


def test_torque_per_normalized_torque_is_pxs_allocation_for_the_rotors() -> None:
    """The figure [controller.attitude_feedforward] takes: for the Firefly layout (0.215 m
    arms, 6 N rotors) a normalized roll or pitch torque of 1 is 3.16 N m, whatever the
    payload; a small torque command around hover makes that much body torque."""
    cfg = load_scenario(CONFIGS / "paper_sim.toml")
    empty, loaded = hover_authority(cfg, False), hover_authority(cfg, True)
    assert empty.torque_per_normalized_n_m == loaded.torque_per_normalized_n_m
    roll, pitch, _ = loaded.torque_per_normalized_n_m
    assert roll == pytest.approx(3.16, rel=2e-3) and pitch == pytest.approx(3.16, rel=2e-3)
    assert loaded.unsaturated_torque_n_m[1] < pitch  # saturates before a command of 1


def test_cli_authority_prints_table_and_rejects_bad_config(run_sitl, tmp_path: Path) -> None:
    ok = run_sitl("authority", "--config", str(CONFIGS / "paper_sim.toml"))
    assert ok.returncode == 0, ok.stderr
    assert "pitch torque" in ok.stdout
    assert "torque per normalized" in ok.stdout and "3.160 / 3.160" in ok.stdout
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 1\n")
    result = run_sitl("authority", "--config", str(bad))
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert f"{bad}: name: " in result.stderr

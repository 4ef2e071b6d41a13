"""The PX4 parameters the model depends on, checked against the config before flight."""

from __future__ import annotations

import pytest

from companion.config import load_config
from companion.mission.vehicle_params import VehicleParams, contradictions

PICKUP = load_config("configs/sitl_pickup.toml")  # motors' curve 0.3
SIH = load_config("configs/px4_sih_pickup.toml")  # linear motors (PX4 SIH)


PX4_LOOP = {
    **{"MC_ROLL_P": 4.0, "MC_PITCH_P": 4.0, "MC_ROLLRATE_P": 0.15, "MC_PITCHRATE_P": 0.15},
    **{"MC_ROLLRATE_I": 0.2, "MC_PITCHRATE_I": 0.2, "MC_ROLLRATE_K": 1.0, "MC_PITCHRATE_K": 1.0},
    **{"MC_RR_INT_LIM": 0.3, "MC_PR_INT_LIM": 0.3},
}
"""PX4 main's defaults (measured on ../shared/px4-sitl), which sitl_pickup.toml models."""


def params(fac=0.3, floor=0.12, rotors=6, **loop):
    return VehicleParams.from_values(
        {"THR_MDL_FAC": fac, "MPC_THR_MIN": floor, "CA_ROTOR_COUNT": rotors, **PX4_LOOP, **loop}
    )


def test_a_vehicle_that_fits_has_no_contradiction():
    assert contradictions(params(), PICKUP) == []
    assert contradictions(params(fac=0.0), SIH) == []
    assert params().describe().startswith("THR_MDL_FAC 0.3, MPC_THR_MIN 0.12, CA_ROTOR_COUNT 6")


def test_px4_linearizing_with_another_curve_is_refused_in_one_sentence():
    """What the issue measured: PX4 SIH (THR_MDL_FAC 0) flown with a config that believed
    a 0.3 curve put the hover at 10.1 N instead of 12 N."""
    (problem,) = contradictions(params(fac=0.0), PICKUP)
    assert "THR_MDL_FAC is 0 but the config's vehicle.rotors.thr_mdl_fac is 0.3" in problem
    assert "\n" not in problem


def test_another_rotor_count_is_refused():
    (problem,) = contradictions(params(rotors=4), PICKUP)
    assert "CA_ROTOR_COUNT is 4" in problem


def test_px4s_battery_scaling_beside_the_companions_is_refused():
    """Both compensating the battery's voltage would count it twice: with MC_BAT_SCALE_EN
    = 1 the companion's thrust scale, carried with the voltage, would fall while PX4 made
    the thrust per command steady. Refused while the config carries it (window_s > 0);
    with PX4's scaling off, or the companion's, nothing to say."""
    (problem,) = contradictions(params(MC_BAT_SCALE_EN=1), PICKUP)
    assert "MC_BAT_SCALE_EN = 1" in problem and "window_s" in problem and "\n" not in problem
    assert contradictions(params(MC_BAT_SCALE_EN=0), PICKUP) == []
    held = PICKUP.estimator.thrust_scale.model_copy(update={"window_s": 0.0})  # type: ignore[union-attr]
    estimator = PICKUP.estimator.model_copy(update={"thrust_scale": held})
    assert (
        contradictions(
            params(MC_BAT_SCALE_EN=1), PICKUP.model_copy(update={"estimator": estimator})
        )
        == []
    )


def test_optional_parameters_may_be_missing_required_ones_not():
    p = VehicleParams.from_values({"THR_MDL_FAC": 0.0, "MPC_THR_MIN": 0.12})
    assert p.rotor_count is None and contradictions(p, SIH) == []
    with pytest.raises(KeyError, match="MPC_THR_MIN"):
        VehicleParams.from_values({"THR_MDL_FAC": 0.3, "MPC_THR_MIN": None})


def test_px4_gains_other_than_the_attitude_feedforwards_are_refused():
    """[controller.attitude_feedforward] inverts PX4's tilt loop: its offsets are wrong by
    the ratio of the gains on a vehicle tuned otherwise; the rate K scales P and I."""
    (problem,) = contradictions(params(MC_PITCHRATE_P=0.3), PICKUP)
    assert "MC_PITCHRATE_P is 0.3" in problem and "rate_p[1] is 0.15" in problem
    problems = contradictions(params(MC_ROLLRATE_K=2.0), PICKUP)
    assert len(problems) == 2
    assert all("x MC_ROLLRATE_K 2" in p for p in problems)
    (problem,) = contradictions(params(MC_PR_INT_LIM=0.1), PICKUP)
    assert "rate_integrator_limit[1]" in problem
    (problem,) = contradictions(params(MC_ROLL_P=6.5), PICKUP)
    assert "MC_ROLL_P is 6.5" in problem
    assert contradictions(params(fac=0.0, MC_ROLL_P=6.5), SIH) == []  # no feed-forward there


def test_a_vehicle_without_the_modelled_parameters_is_refused():
    p = VehicleParams.from_values({"THR_MDL_FAC": 0.3, "MPC_THR_MIN": 0.12, "MC_ROLL_P": 4.0})
    (problem,) = contradictions(p, PICKUP)
    assert "does not answer MC_PITCH_P, MC_ROLLRATE_P" in problem
    assert "remove that section" in problem

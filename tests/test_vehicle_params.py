"""The PX4 parameters the model depends on, checked against the config before flight."""

from __future__ import annotations

import pytest

from companion.config import load_config
from companion.vehicle_params import VehicleParams, contradictions

PICKUP = load_config("configs/sitl_pickup.toml")  # motors' curve 0.3
SIH = load_config("configs/px4_sih_pickup.toml")  # linear motors (PX4 SIH)


def params(fac=0.3, floor=0.12, rotors=6):
    return VehicleParams.from_values(
        {"THR_MDL_FAC": fac, "MPC_THR_MIN": floor, "CA_ROTOR_COUNT": rotors}
    )


def test_a_vehicle_that_fits_has_no_contradiction():
    assert contradictions(params(), PICKUP) == []
    assert contradictions(params(fac=0.0), SIH) == []
    assert "THR_MDL_FAC 0.3, MPC_THR_MIN 0.12, CA_ROTOR_COUNT 6" == params().describe()


def test_px4_linearizing_with_another_curve_is_refused_in_one_sentence():
    """What the issue measured: PX4 SIH (THR_MDL_FAC 0) flown with a config that believed
    a 0.3 curve put the hover at 10.1 N instead of 12 N."""
    (problem,) = contradictions(params(fac=0.0), PICKUP)
    assert "THR_MDL_FAC is 0 but the config's vehicle.rotors.thr_mdl_fac is 0.3" in problem
    assert "\n" not in problem


def test_another_rotor_count_is_refused():
    (problem,) = contradictions(params(rotors=4), PICKUP)
    assert "CA_ROTOR_COUNT is 4" in problem


def test_optional_parameters_may_be_missing_required_ones_not():
    p = VehicleParams.from_values({"THR_MDL_FAC": 0.3, "MPC_THR_MIN": 0.12})
    assert p.rotor_count is None and contradictions(p, PICKUP) == []
    with pytest.raises(KeyError, match="MPC_THR_MIN"):
        VehicleParams.from_values({"THR_MDL_FAC": 0.3, "MPC_THR_MIN": None})

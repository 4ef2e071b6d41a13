"""Tests of arm_driver.dynamixel.units: raw XM430 units <-> SI."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from arm_driver.dynamixel import units


def test_scales_from_the_emanual() -> None:
    assert units.RAD_PER_TICK == 2 * math.pi / 4096  # "0.088 deg/value", rounded
    assert units.RAD_PER_TICK == pytest.approx(math.radians(0.088), rel=2e-3)
    assert units.velocity_units_to_rad_s(1) == pytest.approx(0.229 * 2 * math.pi / 60)
    assert units.current_units_to_a(1193) == pytest.approx(3.209, abs=1e-3)
    assert units.acceleration_units_to_rad_s2(1) == pytest.approx(0.37451, rel=1e-4)
    assert units.voltage_units_to_v(119) == pytest.approx(11.9)
    assert units.temperature_units_to_c(36) == 36.0


def test_position_convention() -> None:
    """2048 pulses is 0 rad by default; a quarter turn is 1024 pulses; CCW positive."""
    assert units.ticks_to_rad(2048) == 0.0
    assert units.ticks_to_rad(2048 + 1024) == pytest.approx(math.pi / 2)
    assert units.ticks_to_rad(0) == pytest.approx(-math.pi)
    assert units.rad_to_ticks(-math.pi / 2) == 1024
    assert units.ticks_to_rad(100, zero_ticks=100) == 0.0
    assert units.rad_to_ticks(0.0, zero_ticks=-5000) == -5000


@given(st.integers(-(2**31), 2**31 - 1), st.integers(0, 4095))
def test_ticks_round_trip(ticks: int, zero: int) -> None:
    assert units.rad_to_ticks(units.ticks_to_rad(ticks, zero), zero) == ticks


@given(st.floats(-100.0, 100.0))
def test_angle_round_trip_within_half_a_tick(angle_rad: float) -> None:
    back = units.ticks_to_rad(units.rad_to_ticks(angle_rad))
    assert abs(back - angle_rad) <= units.RAD_PER_TICK / 2 + 1e-12


@given(st.integers(-(2**15), 2**15 - 1))
def test_rate_and_current_round_trips(count: int) -> None:
    assert units.rad_s_to_velocity_units(units.velocity_units_to_rad_s(count)) == count
    assert units.a_to_current_units(units.current_units_to_a(count)) == count
    assert units.rad_s2_to_acceleration_units(units.acceleration_units_to_rad_s2(count)) == count


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_values_are_refused(value: float) -> None:
    for function in (
        units.rad_to_ticks,
        units.rad_s_to_velocity_units,
        units.a_to_current_units,
        units.rad_s2_to_acceleration_units,
    ):
        with pytest.raises(ValueError, match="not finite"):
            function(value)

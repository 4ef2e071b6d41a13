"""``companion check --timing`` (companion.mission.timing_check): the shipped recording
replayed through the cycle's parts, the table and the verdict. No timed assertion: this
machine holds 125 Hz with a wide margin (the cycle's p99 about 1.2 ms of 8 ms), and no
computer holds 1 MHz; the verdict's arithmetic is checked on made-up times."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from companion.cli.main import app
from companion.config import load_config
from companion.mission.timing_check import (
    PARTS,
    RECORDING,
    CycleInputs,
    TimingResult,
    check_timing,
)

CONFIG = "configs/sitl_pickup.toml"


def _result(rate_hz: float, cycle_us: list[float]) -> TimingResult:
    times = {part: np.asarray(cycle_us) for part in PARTS}
    return TimingResult(rate_hz, times)


def test_the_verdict_is_the_cycles_p99_against_half_the_period():
    at_125 = [1000.0] * 99 + [4000.0]  # p99 at 3970 us: under half of 8000 us
    result = _result(125.0, at_125)
    assert result.keeps_up and result.verdict().startswith("keeps up at 125 Hz")
    assert result.headroom == pytest.approx(1.0 - result.percentile_us("cycle", 99) / 8000.0)
    slow = _result(125.0, [1000.0] * 90 + [4100.0] * 10)  # p99 4100 us: over half
    assert not slow.keeps_up
    assert slow.verdict() == (
        "too slow for 125 Hz: the cycle's p99 is 4100 us, 51 % of the 8000 us control "
        "period (at most 50 %); fly a lower --control-rate or a faster computer"
    )


def test_the_shipped_recording_is_the_estimator_at_work():
    inputs = CycleInputs.load()
    assert len(inputs) == 750
    assert set(inputs.arrays) == set(RECORDING)
    assert np.all(inputs.arrays["skip"] == 0)  # the applied force known every cycle
    assert np.all(inputs.arrays["step_dt_s"] == pytest.approx(0.008))


def test_the_replay_times_every_part_of_every_cycle():
    recording = CycleInputs.load()
    short = CycleInputs({k: v[:50] for k, v in recording.arrays.items()})
    result = check_timing(load_config(CONFIG), 1e6, inputs=short)
    assert set(result.times_us) == set(PARTS)
    for part in PARTS:
        assert len(result.times_us[part]) == 50 and np.all(result.times_us[part] >= 0.0)
    parts = sum(result.times_us[p] for p in PARTS[:-1])
    assert np.all(result.times_us["cycle"] >= parts - 1.0)  # the parts lie inside the cycle


def test_check_timing_at_125_hz_prints_its_table_and_exits_0():
    result = CliRunner().invoke(
        app, ["check", CONFIG, "--timing", "--control-rate", "125"], env={"COLUMNS": "200"}
    )
    assert result.exit_code == 0, result.output
    for part in PARTS:
        assert f"│ {part}" in result.output
    assert "p99 [us]" in result.output and "headroom at the cycle's p99" in result.output
    assert "keeps up at 125 Hz" in result.output


def test_check_timing_at_a_rate_no_computer_holds_exits_1_with_its_verdict():
    result = CliRunner().invoke(
        app, ["check", CONFIG, "--timing", "--control-rate", "1000000"], env={"COLUMNS": "200"}
    )
    assert result.exit_code == 1, result.output
    verdict = [line for line in result.output.splitlines() if line.startswith("too slow")]
    assert (
        len(verdict) == 1 and "for 1e+06 Hz" in verdict[0] and "1 us control period" in verdict[0]
    )

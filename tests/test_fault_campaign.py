"""A slice of the fault campaign (configs/campaigns/faults.toml) in the suite: faults at
four phases, with the heaviest payload at the jaws, each flight judged by docs/faults.md's
numbers. The whole matrix is `sitl campaign configs/campaigns/faults.toml`."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.config import read_toml
from sitl.campaign.flights import expand, scenario_document
from sitl.campaign.fly import fly_flight
from sitl.campaign.spec import load_spec

SPEC = Path(__file__).parent.parent / "configs" / "campaigns" / "faults.toml"
SLICE = (
    "link_cut(at_phase=grasp, offset_s=0.5, duration_s=2)",
    "link_cut(at_phase=to_place, offset_s=0.5, duration_s=10)",
    "servo_silent(servo_id=2, at_phase=lift, offset_s=0.5)",
    "payload_slip(after_grasp_s=10)",
)

pytestmark = pytest.mark.slow


def test_the_shipped_matrix_has_every_fault_at_every_phase():
    flights = expand(load_spec(SPEC), SPEC)
    assert len(flights) >= 200
    phased = {(f.fault.kind, f.fault.at_phase) for f in flights if f.fault.at_phase}
    assert len(phased) == 2 * 12  # link_cut and servo_silent at each of the 12 moments


@pytest.mark.parametrize("label", SLICE)
def test_a_fault_of_the_matrix_ends_safe(label, tmp_path):
    heavy_at_jaws = {"payload.mass_kg": 0.42, "payload.position_m": 0.17}
    (flight,) = [
        f
        for f in expand(load_spec(SPEC), SPEC)
        if f.fault.label() == label
        and all(dict(f.settings)[k] == v for k, v in heavy_at_jaws.items())
    ]
    row = fly_flight(flight, scenario_document(flight, read_toml(Path(flight.base))))
    assert row["status"] == "ok", row.get("error")
    assert row["safe"] == 1, row["unsafe"]
    assert row["outcome"] != "completed"  # each of these ends the pickup, named

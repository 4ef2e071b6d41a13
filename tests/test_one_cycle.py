"""One flight cycle everywhere: the offline simulator and the flight app run the same step.

The offline simulator (``sitl.offline.simulation``) and the flight app
(``companion.mission.app.PickupApp``) both build a
:class:`companion.control.flight.FlightControl` from the companion's configuration and call
its ``step``. Recorded from an offline run (underactuated plant,
noisy sensors), the same sequence of (dt, filtered state, desired state, applied force)
replayed through the app's own FlightControl gives bit-identical setpoints and torques:
there is no second copy of the cycle to drift apart.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_app_in_process import PoseLink, ScriptedPoses, TwoJoints

from companion.control.flight import FlightControl
from companion.estimation.estimator import Skip
from companion.mission.app import PickupApp
from companion.mission.pickup import PickupPlan
from sitl.offline.simulation import SimOptions, simulate
from sitl.scenario import load_scenario

SCENARIO = load_scenario("configs/sitl_pickup.toml")


@pytest.mark.parametrize("controller", ["passivity", "nonadaptive"])
def test_the_app_replays_the_offline_cycle_bit_for_bit(controller, monkeypatch):
    recorded = []
    step = FlightControl.step

    def recording(self, dt_s, state, desired, applied):
        out = step(self, dt_s, state, desired, applied)
        kept = applied if isinstance(applied, Skip) else np.array(applied)
        recorded.append(((dt_s, state, desired, kept), out))
        return out

    monkeypatch.setattr(FlightControl, "step", recording)
    simulate(
        SCENARIO,
        SimOptions(controller=controller, plant="underactuated", noise=True, duration_s=1.0),
    )
    monkeypatch.setattr(FlightControl, "step", step)
    assert len(recorded) > 100

    plan = PickupPlan(home_m=(0.0, 0.0), payload_at_m=(1.0, 0.0, 0.0), place_at_m=(2.0, 0, 0))
    app = PickupApp(
        SCENARIO.beliefs, PoseLink(ScriptedPoses(8000)), TwoJoints(), plan, controller=controller
    )
    assert type(app.control) is FlightControl and app.control.rows == (0, 1, 2, 6, 7)
    app.control.estimator.resume()  # the app holds it frozen until PX4 flies its setpoints
    for (dt_s, state, desired, applied), offline in recorded:
        replayed = app.control.step(dt_s, state, desired, applied)
        assert replayed.setpoint == offline.setpoint
        np.testing.assert_array_equal(replayed.tau, offline.tau)
        np.testing.assert_array_equal(replayed.estimate.theta, offline.estimate.theta)

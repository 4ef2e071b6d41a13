"""Failsafe monitor: each fault raised once, after its hold time, with its reactions."""

import pytest

from companion.mission.failsafe import FailsafeMonitor, Fault, Reaction


def run(monitor, seconds, dt=0.01, **flags):
    events = []
    t = getattr(monitor, "_t", 0.0)
    for _ in range(round(seconds / dt)):
        events += monitor.update(
            t,
            on_bound=flags.get("on_bound", False),
            tilt_saturated=flags.get("tilt", False),
            thrust_saturated=flags.get("thrust", False),
        )
        t += dt
    monitor._t = t
    return events


def test_short_saturations_are_tolerated_and_a_lasting_one_aborts():
    monitor = FailsafeMonitor(saturation_hold_s=2.0)
    for _ in range(5):
        assert run(monitor, 1.5, tilt=True) == []
        assert run(monitor, 0.1) == []
    events = run(monitor, 2.5, thrust=True)
    assert [e.fault for e in events] == [Fault.SATURATION]
    assert events[0].reactions == (Reaction.FREEZE_ESTIMATE, Reaction.HOLD_THEN_LAND)
    assert "thrust" in events[0].detail
    assert monitor.aborted


def test_estimate_on_bound_freezes_without_aborting():
    monitor = FailsafeMonitor(bound_hold_s=1.0)
    events = run(monitor, 1.5, on_bound=True)
    assert [e.fault for e in events] == [Fault.ESTIMATE_BOUND]
    assert not events[0].aborts and not monitor.aborted
    assert run(monitor, 3.0, on_bound=True) == []  # raised once


def test_external_faults_are_raised_once():
    monitor = FailsafeMonitor()
    first = monitor.raise_fault(3.0, Fault.SERVO_BUS, "servo 2 timed out")
    assert first is not None and first.aborts
    assert Reaction.LAND in first.reactions
    assert monitor.raise_fault(4.0, Fault.SERVO_BUS, "again") is None
    assert monitor.has(Fault.SERVO_BUS) and not monitor.has(Fault.LINK_LOST)


def test_hold_times_must_be_positive():
    with pytest.raises(ValueError):
        FailsafeMonitor(bound_hold_s=0.0)

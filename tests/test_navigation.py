"""The navigation watch: EKF resets and estimates too uncertain to fly on."""

from __future__ import annotations

import pytest

from companion.link.telemetry import VehiclePose
from companion.mission.navigation import NavigationWatch

Q = (1.0, 0.0, 0.0, 0.0)


def pose(counter=3, pos_var=(0.04, 0.04, 0.002), vel_var=(0.01, 0.01, 0.001), v=(0, 0, 0)):
    return VehiclePose(0, (0.0, 0.0, 1.0), v, Q, pos_var, vel_var, counter)


def test_a_changed_reset_counter_is_a_reset_once():
    watch = NavigationWatch(1.0, 0.5, 0.5)
    assert not watch.update(0.0, pose(3)).reset  # the first counter is just learnt
    assert watch.update(0.01, pose(4)).reset
    assert not watch.update(0.02, pose(4)).reset
    assert watch.resets == 1


def test_variance_beyond_the_limit_is_a_fault_after_the_hold_time_once():
    watch = NavigationWatch(1.0, 0.5, 0.5)
    assert watch.update(0.0, pose()).problem is None
    bad = pose(pos_var=(2.0, 0.04, 0.002))  # 1.41 m std
    first = watch.update(1.0, bad)
    assert "position estimate std 1.41 m" in first.problem and first.fault is None
    assert watch.update(1.4, bad).fault is None
    fault = watch.update(1.5, bad).fault
    assert fault is not None and "for 0.5 s" in fault
    assert watch.update(1.6, bad).fault is None  # reported once
    assert watch.update(1.7, pose()).problem is None
    assert watch.update(3.0, bad).fault is None and watch.update(3.5, bad).fault is not None


@pytest.mark.parametrize(
    ("p", "why"),
    [
        (pose(v=None), "no valid velocity"),
        (pose(vel_var=(0.01, 0.36, 0.01)), "velocity estimate std 0.60 m/s"),
    ],
)
def test_velocity_problems(p, why):
    assert why in NavigationWatch(1.0, 0.5, 0.5).update(0.0, p).problem


def test_a_pose_without_variances_is_not_judged():
    watch = NavigationWatch(1.0, 0.5, 0.5)
    check = watch.update(0.0, VehiclePose(0, (0.0, 0.0, 1.0), (0.0, 0.0, 0.0), Q))
    assert check.problem is None and not check.reset

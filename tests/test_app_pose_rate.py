"""Preflight: the ODOMETRY stream that clocks the control loop must come fast enough.

The app's measurement runs in-process here on a scripted pose stream (the end-to-end tests
fly it against the SITL at the full rate); the link and bus stand-ins provide only what
``PickupApp`` reads before take-off.
"""

from __future__ import annotations

import asyncio
import contextlib

import pytest

from arm_driver.bus import JointConfig
from companion.app import MissionError, PickupApp
from companion.config import load_scenario
from companion.link.telemetry import VehiclePose
from companion.mission import PickupPlan

SCENARIO = load_scenario("configs/sitl_pickup.toml")
PLAN = PickupPlan(home_m=(0.0, 0.0), payload_at_m=(1.0, 0.0, 0.0), place_at_m=(2.0, 0.0, 0.0))


class ScriptedPoses:
    """A pose subscription that yields one pose per ``period_ms`` of vehicle time."""

    def __init__(self, period_ms: int, repeat_each: int = 1) -> None:
        self.period_ms = period_ms
        self.repeat_each = repeat_each
        self.count = 0

    async def get(self) -> VehiclePose:
        await asyncio.sleep(0)
        t_ms = (self.count // self.repeat_each) * self.period_ms
        self.count += 1
        return VehiclePose(t_ms, (0.0, 0.0, 0.0), None, (1.0, 0.0, 0.0, 0.0))


class PoseLink:
    def __init__(self, poses: ScriptedPoses) -> None:
        self.poses = poses

    @contextlib.contextmanager
    def subscribe(self, *keys, maxsize: int = 64):
        assert keys == (VehiclePose,)
        yield self.poses


class TwoJoints:
    joints = (JointConfig("eta1", 1, 1.78, 1.5), JointConfig("eta2", 2, 1.78, 1.5))

    def torque_limit_n_m(self, name: str) -> float:
        return 1.5


def check(period_ms: int, repeat_each: int = 1) -> list[tuple[str, str]]:
    notes: list[tuple[str, str]] = []
    app = PickupApp(
        SCENARIO,
        PoseLink(ScriptedPoses(period_ms, repeat_each)),
        TwoJoints(),
        PLAN,
        event=lambda kind, detail, t_s: notes.append((kind, detail)),
    )
    asyncio.run(app._check_pose_rate())
    return notes


def test_full_rate_passes_quietly():
    assert check(4) == []


def test_repeated_timestamps_are_one_pose():
    assert check(4, repeat_each=3) == []


def test_slower_than_asked_but_within_the_gains_is_noted():
    notes = check(10)
    assert notes and notes[0][0] == "loop" and "10.0 ms" in notes[0][1]


def test_too_slow_for_the_gains_refuses_to_fly():
    with pytest.raises(MissionError, match=r"every 50\.0 ms .* below 35\.\d ms"):
        check(50)

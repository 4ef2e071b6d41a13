"""Whether the pickup carries its object: the gripper and estimate witnesses, and the
mission's way home when it does not (pure: no flight)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.config import load_config
from companion.coordinates import JOINTS, POSITION, Z
from companion.mission.carry_check import (
    EMPTY_READINGS,
    CarryThresholds,
    CarryWatch,
    gripper_holds,
)
from companion.mission.failsafe import CARRY_REACTIONS, Reaction
from companion.mission.pickup import (
    EstimatorAction,
    GripperAction,
    Outcome,
    Phase,
    PickupMission,
    PickupPlan,
)

SCENARIO = load_config("configs/sitl_pickup.toml")
GRIPPER = SCENARIO.arm_bus.gripper  # open +45 deg, closed -15 deg
THRESHOLDS = CarryThresholds()
EMPTY_M2 = SCENARIO.nominal_theta.m2_kg


def holds(position_rad: float, current_a: float = math.nan) -> bool:
    return gripper_holds(
        position_rad,
        current_a,
        GRIPPER.open_position_rad,
        GRIPPER.closed_position_rad,
        THRESHOLDS,
    )


def test_gripper_stopped_short_and_pushing_holds_and_at_closed_holds_nothing():
    closed = GRIPPER.closed_position_rad
    assert holds(closed + 0.2, current_a=-2.1)
    assert not holds(closed, current_a=0.0)
    assert not holds(closed + 0.05, current_a=-2.1)  # within the margin of closed
    assert not holds(closed + 0.2, current_a=0.0)  # stopped short but not pushing: still open
    assert holds(closed + 0.2)  # a bus without current: the position alone
    assert not holds(closed - 0.05)  # past closed (mechanical slack) is not toward open


def test_gripper_closing_the_other_way_is_mirrored():
    args = (-0.8, 0.25, THRESHOLDS)  # open at -0.8, closed at +0.25
    assert gripper_holds(0.05, -1.0, *args)
    assert not gripper_holds(0.25, 0.0, *args)


def test_thresholds_reject_nonsense():
    with pytest.raises(ValueError):
        CarryThresholds(gripper_margin_rad=0.0)
    with pytest.raises(ValueError):
        CarryThresholds(gripper_current_a=-1.0)


def test_a_grasp_on_nothing_fails_and_on_the_object_is_seen():
    verdict = CarryWatch(THRESHOLDS, EMPTY_M2).grasp(False)
    assert verdict is not None and verdict.outcome == Outcome.GRASP_FAILED
    watch = CarryWatch(THRESHOLDS, EMPTY_M2)
    assert watch.grasp(True) is None and watch.seen
    assert CarryWatch(THRESHOLDS, EMPTY_M2).grasp(None) is None  # not readable: no word


def test_an_object_seen_then_gripper_empty_twice_is_lost_once_is_not():
    watch = CarryWatch(THRESHOLDS, EMPTY_M2)
    watch.grasp(True)
    assert watch.gripper(True) is None
    assert watch.gripper(False) is None  # one reading: could be a glitch
    assert watch.gripper(True) is None  # and it was
    verdicts = [watch.gripper(False) for _ in range(EMPTY_READINGS)]
    assert verdicts[:-1] == [None] * (EMPTY_READINGS - 1)
    assert verdicts[-1] is not None and verdicts[-1].outcome == Outcome.PAYLOAD_LOST
    assert "slipped out of the gripper" in verdicts[-1].detail  # not a grasp's words
    never = CarryWatch(THRESHOLDS, EMPTY_M2)
    verdict = [never.gripper(False) for _ in range(EMPTY_READINGS)][-1]
    assert verdict is not None and verdict.outcome == Outcome.GRASP_FAILED
    assert "grasp did not take" in verdict.detail


def test_a_confident_estimate_of_the_empty_arm_carries_nothing():
    watch = CarryWatch(THRESHOLDS, EMPTY_M2)
    assert watch.estimate(EMPTY_M2 + 0.01, confident=False) is None  # not yet confident
    verdict = watch.estimate(EMPTY_M2 + 0.01, confident=True)
    assert verdict is not None and verdict.outcome == Outcome.GRASP_FAILED  # never seen
    assert "m2 = 0.130 kg" in verdict.detail
    loaded = CarryWatch(THRESHOLDS, EMPTY_M2)
    assert loaded.estimate(EMPTY_M2 + 0.25, confident=True) is None and loaded.seen
    verdict = loaded.estimate(EMPTY_M2 + 0.02, confident=True)
    assert verdict is not None and verdict.outcome == Outcome.PAYLOAD_LOST
    assert verdict.detail.startswith("the object was lost")


PLAN = PickupPlan(home_m=(0.0, 0.0), payload_at_m=(1.0, 0.0, 0.05), place_at_m=(-1.0, 0.0, 0.05))


def fly_to(mission: PickupMission, phase: Phase, t_s: float = 0.0, dt_s: float = 0.02):
    """Step the mission along its own desired state until ``phase`` starts."""
    q = np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0, 0.0, -1.5])
    while mission.phase != phase:
        assert t_s < 300.0, f"{phase} not reached"
        t_s += dt_s
        q = mission.update(t_s, q, confident=True).desired.q
    return t_s, q


@pytest.mark.parametrize(
    ("outcome", "at", "gripper"),
    [
        (Outcome.GRASP_FAILED, Phase.LIFT, GripperAction.OPEN),
        (Outcome.PAYLOAD_LOST, Phase.TO_PLACE, GripperAction.HOLD),
        (Outcome.BEYOND_AUTHORITY, Phase.LIFT, GripperAction.OPEN),
    ],
)
def test_abandon_climbs_where_it_is_resets_the_estimate_goes_home_and_never_completes(
    outcome, at, gripper
):
    mission = PickupMission(PLAN, SCENARIO)
    mission.start(0.0, np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0, 0.0, -1.5]))
    t_s, q = fly_to(mission, at)
    t_s += 0.3
    q = mission.update(t_s, q, confident=True).desired.q
    command = mission.abandon(t_s, outcome, "test")
    assert command.phase == Phase.RETURN and command.phase_changed
    assert command.estimator == EstimatorAction.EMPTY and command.gripper == gripper
    # What it does is what the failsafe table says it does.
    reactions = CARRY_REACTIONS[outcome]
    assert (gripper == GripperAction.OPEN) == (Reaction.OPEN_GRIPPER in reactions)
    assert {Reaction.RESET_ESTIMATE, Reaction.RETURN_HOME, Reaction.LAND} <= set(reactions)
    np.testing.assert_allclose(command.desired.q, q, atol=1e-9)  # continuous: no jump
    again = mission.abandon(t_s + 0.1, Outcome.PAYLOAD_LOST, "twice")
    assert not again.phase_changed and mission.outcome == outcome
    # Up to cruise altitude where it was, at least return_hold_s, arm down, estimator held.
    start_xy = q[POSITION][:2].copy()
    t_return = t_s
    while mission.phase == Phase.RETURN:
        t_s += 0.02
        command = mission.update(t_s, q, confident=False)
        q = command.desired.q
        if command.phase == Phase.RETURN:  # where it was (the carry's speed run out)
            assert np.linalg.norm(q[POSITION][:2] - start_xy) < 0.05
            assert command.estimator == EstimatorAction.FREEZE
            end_xy = q[POSITION][:2].copy()
    np.testing.assert_allclose(end_xy, start_xy, atol=1e-9)
    assert t_s - t_return >= PLAN.return_hold_s
    assert mission.phase == Phase.TO_HOME and q[Z] == pytest.approx(PLAN.cruise_altitude_m)
    assert mission.update(t_s, q, confident=True).estimator == EstimatorAction.FREEZE
    t_s, q = fly_to(mission, Phase.DONE, t_s)
    np.testing.assert_allclose(q[POSITION][:2], PLAN.home_m, atol=1e-9)
    np.testing.assert_allclose(q[JOINTS], PLAN.stow_joints_rad)
    phases = [p for _, p in mission.phase_log]
    assert Phase.RELEASE not in phases and phases[-3:] == [Phase.RETURN, Phase.TO_HOME, Phase.DONE]
    assert mission.outcome == outcome and mission.outcome_detail == "test"


def test_abandon_needs_a_reason():
    mission = PickupMission(PLAN, SCENARIO)
    mission.start(0.0, np.zeros(8))
    with pytest.raises(ValueError):
        mission.abandon(1.0, Outcome.COMPLETED, "")


class GripperBus:
    """An arm bus stand-in: joints answer, the gripper reads as given (or cannot)."""

    joints = ()
    watchdog_s = 0.0

    def __init__(self, readable: bool) -> None:
        self.readable = readable
        self.gripper_reads = 0

    def torque_limit_n_m(self, name: str) -> float:
        return 1.0

    async def read_joint_states(self):
        return {}

    async def read_gripper(self):
        from arm_driver.bus import BusStateError, GripperState

        if not self.readable:
            raise BusStateError("this bus cannot read the gripper's state")
        self.gripper_reads += 1
        return GripperState(GRIPPER.closed_position_rad + 0.2, -2.1, 0.0)


def test_the_arm_task_reads_the_gripper_only_while_watched_and_notes_a_bus_that_cannot():
    import asyncio

    from companion.mission.arm_supervisor import ArmSupervisor

    async def turns(supervisor: ArmSupervisor, n: int) -> None:
        for _ in range(n):
            supervisor.due()
            await asyncio.sleep(0.06)

    async def body(bus: GripperBus, notes: list):
        supervisor = ArmSupervisor(
            bus,
            vehicle_time=lambda: 0.0,
            note=lambda kind, text: notes.append((kind, text)),
            on_failure=lambda reason: None,
        )
        task = asyncio.create_task(supervisor.run())
        await turns(supervisor, 3)
        unwatched = supervisor.take_gripper()
        supervisor.watch_gripper(True)
        await turns(supervisor, 6)
        watched = supervisor.take_gripper()
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        return supervisor, unwatched, watched

    notes: list = []
    supervisor, unwatched, watched = asyncio.run(body(GripperBus(True), notes))
    assert unwatched is None and watched is not None and watched.current_a == -2.1
    assert supervisor.bus.gripper_reads >= 1 and notes == []
    notes = []
    supervisor, _, watched = asyncio.run(body(GripperBus(False), notes))
    assert watched is None and not supervisor.gripper_readable
    assert [kind for kind, _ in notes] == ["gripper"] and "estimate alone" in notes[0][1]


class FlakyGripperBus(GripperBus):
    """A gripper whose first ``timeouts`` commands time out (a late reply on a slow bus)."""

    def __init__(self, timeouts: int) -> None:
        super().__init__(True)
        self.timeouts = timeouts
        self.closed = False

    async def close_gripper(self):
        from arm_driver.errors import BusTimeoutError

        if self.timeouts > 0:
            self.timeouts -= 1
            raise BusTimeoutError(3, 0.02)
        self.closed = True


@pytest.mark.parametrize("timeouts", [1, 2])
def test_a_gripper_command_that_timed_out_is_sent_again_once(timeouts):
    import asyncio

    from companion.mission.arm_supervisor import GRIPPER_ATTEMPTS, ArmSupervisor
    from companion.mission.pickup import GripperAction

    async def body():
        lost: list[str] = []
        supervisor = ArmSupervisor(
            FlakyGripperBus(timeouts),
            vehicle_time=lambda: 0.0,
            note=lambda kind, text: None,
            on_failure=lost.append,
        )
        task = asyncio.create_task(supervisor.run())
        supervisor.grip(GripperAction.CLOSE)
        supervisor.due()
        await asyncio.sleep(0.05)
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        return supervisor, lost

    supervisor, lost = asyncio.run(body())
    if timeouts < GRIPPER_ATTEMPTS:
        assert supervisor.bus.closed and lost == [] and not supervisor.failed
    else:
        assert not supervisor.bus.closed and supervisor.failed
        assert len(lost) == 1 and lost[0].startswith("gripper: servo 3")


def test_abandon_in_the_excitation_leaves_the_swing_without_a_jump_in_velocity():
    mission = PickupMission(PLAN, SCENARIO)
    mission.start(0.0, np.array([0.0, 0.0, 1.5, 0.0, 0.0, 0.0, 0.0, -1.5]))
    t_s, q = fly_to(mission, Phase.EXCITE)
    t_s += 2.3  # mid-swing
    before = mission.update(t_s, q, confident=False).desired
    assert np.abs(before.q_dot[JOINTS]).max() > 0.05
    after = mission.abandon(t_s, Outcome.PAYLOAD_LOST, "test").desired
    np.testing.assert_allclose(after.q, before.q, atol=1e-12)
    np.testing.assert_allclose(after.q_dot[POSITION], before.q_dot[POSITION], atol=1e-12)
    np.testing.assert_allclose(after.q_dot[JOINTS], before.q_dot[JOINTS], atol=1e-12)

"""Real-time scheduling of the control thread (:mod:`companion.mission.scheduling`): asked for,
kept, refused, given back; the flight app notes it and restores it after the mission.

The OS calls are replaced where a test needs a refusal or a policy it cannot set; one test
makes the real call in a thread of its own where this user may."""

from __future__ import annotations

import asyncio
import os
import threading
import time

import pytest
from test_app_in_process import PLAN, SCENARIO, PoseLink, ScriptedPoses, TwoJoints

import companion.mission.scheduling as scheduling
from companion.config import ConfigError, parse_config
from companion.mission.app import MissionError, PickupApp
from companion.mission.scheduling import ThreadTimes, enter_real_time

pytestmark = pytest.mark.skipif(
    not hasattr(os, "sched_setscheduler"), reason="no POSIX scheduling calls on this OS"
)


class FakeOs:
    """The calling thread's policy as the scheduling module sees it; records the sets."""

    def __init__(self, monkeypatch, policy: int, priority: int = 0, refuse: bool = False):
        self.policy, self.priority, self.refuse = policy, priority, refuse
        self.sets: list[tuple[int, int]] = []
        monkeypatch.setattr(scheduling.os, "sched_getscheduler", lambda pid: self.policy)
        monkeypatch.setattr(
            scheduling.os, "sched_getparam", lambda pid: os.sched_param(self.priority)
        )
        monkeypatch.setattr(scheduling.os, "sched_setscheduler", self.set)

    def set(self, pid: int, policy: int, param: os.sched_param) -> None:
        assert pid == 0
        if self.refuse:
            raise PermissionError(1, "Operation not permitted")
        self.sets.append((policy, param.sched_priority))
        self.policy, self.priority = policy, param.sched_priority


def test_normal_scheduling_becomes_fifo_and_is_given_back(monkeypatch):
    fake = FakeOs(monkeypatch, os.SCHED_OTHER)
    taken = enter_real_time(50)
    assert (taken.policy, taken.note) == ("SCHED_FIFO 50", None)
    assert fake.sets == [(os.SCHED_FIFO, 50)]
    taken.restore()
    assert fake.sets[-1] == (os.SCHED_OTHER, 0) and fake.policy == os.SCHED_OTHER


def test_a_real_time_policy_already_set_is_kept(monkeypatch):
    fake = FakeOs(monkeypatch, os.SCHED_RR, priority=70)
    kept = enter_real_time(50)
    assert (kept.policy, kept.note) == ("SCHED_RR 70", None)
    kept.restore()
    assert fake.sets == []


def test_another_refusal_is_a_note_too(monkeypatch):
    def refuse(pid, policy, param):
        raise OSError(22, "Invalid argument")

    FakeOs(monkeypatch, os.SCHED_OTHER)
    monkeypatch.setattr(scheduling.os, "sched_setscheduler", refuse)
    refused = enter_real_time(50)
    assert refused.policy == "normal"
    assert "priority 50 refused (Invalid argument)" in (refused.note or "")


def test_a_refusal_is_a_note_not_an_error(monkeypatch):
    fake = FakeOs(monkeypatch, os.SCHED_OTHER, refuse=True)
    refused = enter_real_time(50)
    assert refused.policy == "normal"
    assert refused.note is not None
    assert "priority 50 (flight.realtime_priority) is not permitted" in refused.note
    refused.restore()
    assert fake.sets == []


def test_priority_0_leaves_normal_scheduling_with_a_note(monkeypatch):
    fake = FakeOs(monkeypatch, os.SCHED_OTHER)
    left = enter_real_time(0)
    assert left.policy == "normal" and "realtime_priority = 0" in (left.note or "")
    assert "chrt --fifo 50" in (left.note or "")
    assert fake.sets == []


def test_an_os_without_scheduling_calls_is_a_note(monkeypatch):
    monkeypatch.delattr(scheduling.os, "sched_getscheduler")
    unknown = enter_real_time(50)
    assert unknown.policy == "unknown" and "cannot set" in (unknown.note or "")
    unknown.restore()


@pytest.mark.parametrize("priority", [-1, 100])
def test_a_priority_outside_1_99_is_refused(priority):
    with pytest.raises(ValueError, match="1-99"):
        enter_real_time(priority)


def test_the_config_refuses_a_priority_linux_has_not():
    raw = SCENARIO.model_dump(mode="python")
    raw["flight"]["realtime_priority"] = 120
    with pytest.raises(ConfigError, match="realtime_priority"):
        parse_config(raw)


def test_the_real_call_in_a_thread_of_its_own():
    """Where this user may (root, CAP_SYS_NICE, rtprio), the thread runs SCHED_FIFO and
    gets its policy back; the test's own thread is never touched."""
    if os.sched_getscheduler(0) in (os.SCHED_FIFO, os.SCHED_RR):
        pytest.skip("the test process already runs under a real-time policy (kept as is)")
    seen: dict[str, object] = {}

    def work() -> None:
        taken = enter_real_time(10)
        seen["taken"] = taken
        seen["during"] = os.sched_getscheduler(0)
        taken.restore()
        seen["after"] = os.sched_getscheduler(0)

    before = os.sched_getscheduler(0)
    thread = threading.Thread(target=work)
    thread.start()
    thread.join()
    assert os.sched_getscheduler(0) == before
    taken = seen["taken"]
    if taken.policy == "normal":
        pytest.skip(f"this user may not set SCHED_FIFO: {taken.note}")
    assert taken.policy == "SCHED_FIFO 10"
    assert seen["during"] == os.SCHED_FIFO
    assert seen["after"] == os.SCHED_OTHER


def _app(events: list[tuple[str, str]]) -> PickupApp:
    """A flight app whose events land in ``events`` as (kind, text)."""
    return PickupApp(
        SCENARIO,
        PoseLink(ScriptedPoses(4000)),
        TwoJoints(),
        PLAN,
        event=lambda kind, text, t_s: events.append((kind, text)),
    )


def test_the_app_flies_the_mission_under_fifo_and_gives_it_back(monkeypatch):
    fake = FakeOs(monkeypatch, os.SCHED_OTHER)
    events: list[tuple[str, str]] = []
    app = _app(events)
    during: list[int] = []

    async def fly():
        during.append(fake.policy)
        raise MissionError("preflight: stopped here")

    monkeypatch.setattr(app, "_fly", fly)
    with pytest.raises(MissionError, match="stopped here"):
        asyncio.run(app.run())
    assert during == [os.SCHED_FIFO]
    assert fake.policy == os.SCHED_OTHER
    assert app.report.scheduling == "SCHED_FIFO 50" == app.report.as_dict()["scheduling"]
    assert ("loop", "control loop under SCHED_FIFO 50") in events


def test_the_app_notes_a_refusal_and_flies_normal(monkeypatch):
    FakeOs(monkeypatch, os.SCHED_OTHER, refuse=True)
    events: list[tuple[str, str]] = []
    app = _app(events)

    async def fly():
        raise MissionError("preflight: stopped here")

    monkeypatch.setattr(app, "_fly", fly)
    with pytest.raises(MissionError):
        asyncio.run(app.run())
    assert app.report.scheduling == "normal"
    [(kind, text)] = events
    assert kind == "loop" and "not permitted" in text


@pytest.mark.skipif(
    not os.path.exists("/proc/thread-self/schedstat"), reason="no scheduler statistics here"
)
def test_thread_times_are_the_opening_threads_own():
    """The loop's window reads its own thread's time on a CPU: 50 ms of spinning shows, a
    thread that slept meanwhile shows none of it."""
    slept: list[float] = []

    def sleeper() -> None:
        times = ThreadTimes()
        before = times.read()
        time.sleep(0.1)
        after = times.read()
        times.close()
        assert before is not None and after is not None
        slept.append(after[0] - before[0])

    times = ThreadTimes()
    before = times.read()
    thread = threading.Thread(target=sleeper)
    thread.start()
    start = time.thread_time()
    while time.thread_time() - start < 0.05:
        pass
    after = times.read()
    thread.join()
    times.close()
    assert before is not None and after is not None
    assert 0.045 <= after[0] - before[0] < 1.0 and after[1] >= before[1] >= 0.0
    assert slept[0] < 0.02
    assert times.read() is None  # closed

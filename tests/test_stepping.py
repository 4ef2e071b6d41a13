"""sitl.stepping: the wall-clock slots of the simulator's steps, the end of a run, and the
one stepping loop over them (on a fake clock: what is asserted is the schedule, not this
machine's timing)."""

from __future__ import annotations

import threading

import pytest

from sitl import stepping
from sitl.stepping import WallPacer, running


class _Clock:
    """time.perf_counter and time.sleep on a clock that moves only when told."""

    def __init__(self) -> None:
        self.now = 100.0
        self.sleeps: list[float] = []

    def perf_counter(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += seconds


@pytest.fixture
def clock(monkeypatch) -> _Clock:
    fake = _Clock()
    monkeypatch.setattr(stepping, "time", fake)
    return fake


def test_steps_on_time_wait_for_their_slots(clock) -> None:
    """GIVEN 1 ms slots and steps that take 0.4 ms WHEN paced THEN each step starts in its
    slot, on time, after sleeping the rest of the millisecond."""
    pacer = WallPacer(1e-3, 0.02)
    starts = []
    for _ in range(5):
        assert pacer.wait() == pytest.approx(0.0, abs=1e-12)
        starts.append(clock.now)
        clock.now += 4e-4
    assert starts == pytest.approx([100.0, 100.001, 100.002, 100.003, 100.004])
    assert clock.sleeps == pytest.approx([6e-4] * 4)
    assert pacer.slept_s == pytest.approx(2.4e-3) and pacer.overruns == 0


def test_a_late_step_is_caught_up_within_the_largest_lag(clock) -> None:
    """GIVEN a step that took 5 ms of 1 ms slots (lag limit 20 ms) WHEN paced THEN the next
    steps start late by 4, 3, 2, 1 ms, back to back, and then on their slots again."""
    pacer = WallPacer(1e-3, 0.02)
    pacer.wait()
    clock.now += 5e-3
    late = []
    for _ in range(5):
        late.append(pacer.wait())
    assert late == pytest.approx([4e-3, 3e-3, 2e-3, 1e-3, 0.0], abs=1e-12)
    assert pacer.overruns == 0 and sum(clock.sleeps) < 1e-9  # back to back


def test_a_step_beyond_the_largest_lag_is_an_overrun_and_the_slots_start_again(clock) -> None:
    """GIVEN a 50 ms stall (lag limit 20 ms) WHEN paced THEN one overrun, that step counts
    as on time, and the next slot is one step after it."""
    pacer = WallPacer(1e-3, 0.02)
    pacer.wait()
    clock.now += 0.05
    assert pacer.wait() == 0.0 and pacer.overruns == 1
    resumed = clock.now
    assert pacer.wait() == pytest.approx(0.0, abs=1e-12)
    assert clock.now == pytest.approx(resumed + 1e-3)


def test_restart_makes_the_next_slot_now(clock) -> None:
    """GIVEN a pacer whose next slot lies ahead WHEN restarted after an outside wait (a
    lockstep client's setpoint) THEN the next step starts at once, on time."""
    pacer = WallPacer(1e-3, 0.02)
    pacer.wait()
    clock.now += 3e-3
    pacer.restart()
    assert pacer.wait() == 0.0 and clock.sleeps == []


def test_the_stop_event_wakes_a_waiting_pacer() -> None:
    """GIVEN a pacer with 10 s slots and its loop's stop set WHEN it waits for the second
    slot THEN it returns at once (the event's wait, not a sleep)."""
    stop = threading.Event()
    pacer = WallPacer(10.0, 1.0, stop)
    pacer.wait()
    stop.set()
    late = []
    thread = threading.Thread(target=lambda: late.append(pacer.wait()))
    thread.start()
    thread.join(timeout=5.0)
    assert not thread.is_alive() and late == [0.0]


def test_a_run_ends_when_stopped_or_at_its_time() -> None:
    stop = threading.Event()
    assert running(stop, 0.0, 1e-3)
    assert running(stop, 0.9985, 1e-3, until_s=1.0)
    assert not running(stop, 0.9996, 1e-3, until_s=1.0)  # within half a step of the end
    stop.set()
    assert not running(stop, 0.0, 1e-3)


def test_a_pacer_needs_positive_times() -> None:
    with pytest.raises(ValueError, match="wall_step_s"):
        WallPacer(0.0, 0.02)
    with pytest.raises(ValueError, match="max_lag_s"):
        WallPacer(1e-3, 0.0)


class _Host:
    """A host of ``step_loop`` on the fake clock: each step takes ``step_wall_s`` of wall
    time; ``waits_at`` the steps after which it waited outside its slots (a lockstep
    client), ``paced_from`` the first step it wants paced (PX4's boot before it)."""

    def __init__(
        self,
        clock: _Clock,
        step_wall_s: float = 4e-4,
        waits_at: tuple[int, ...] = (),
        paced_from: int = 0,
        stop: threading.Event | None = None,
        stop_at: int | None = None,
    ) -> None:
        self.clock, self.step_wall_s = clock, step_wall_s
        self.waits_at, self.paced_from = waits_at, paced_from
        self.stop, self.stop_at = stop, stop_at
        self.dt_s = 1e-3
        self.steps = 0
        self.starts: list[float] = []

    @property
    def time_s(self) -> float:
        return self.steps * self.dt_s

    @property
    def paced(self) -> bool:
        return self.steps >= self.paced_from

    def advance(self) -> bool:
        self.starts.append(self.clock.now)
        self.clock.now += self.step_wall_s
        self.steps += 1
        if self.stop is not None and self.steps == self.stop_at:
            self.stop.set()
        if self.steps in self.waits_at:
            self.clock.now += 0.05  # the client's setpoint came 50 ms later
            return True
        return False


def test_without_a_pacer_the_steps_run_back_to_back_to_the_end(clock) -> None:
    """GIVEN no pacer WHEN looped until 10 ms THEN ten steps, nothing slept, the stats say
    so."""
    host = _Host(clock)
    stats = stepping.step_loop(host, until_s=0.01)
    assert host.steps == stats.steps == 10 and clock.sleeps == []
    assert stats.sim_time_s == pytest.approx(0.01) and stats.wall_time_s == pytest.approx(4e-3)
    assert stats.lateness_us == [] and stats.overruns == 0


def test_paced_steps_keep_their_slots_and_a_wait_outside_them_restarts_the_slots(clock) -> None:
    """GIVEN 1 ms slots, and a host that waits 50 ms for a client after its 3rd step WHEN
    looped for 6 steps THEN steps 1-3 start 1 ms apart, step 4 at once after the wait (on
    time, no overrun: the slots started again), 5 and 6 1 ms after it."""
    host = _Host(clock, waits_at=(3,))
    stats = stepping.step_loop(host, until_s=0.006, pacer=WallPacer(1e-3, 0.02))
    t0 = host.starts[0]
    resumed = t0 + 2e-3 + 4e-4 + 0.05
    assert host.starts == pytest.approx(
        [t0, t0 + 1e-3, t0 + 2e-3, resumed, resumed + 1e-3, resumed + 2e-3]
    )
    assert stats.lateness_us == pytest.approx([0.0] * 6, abs=1e-6)
    assert stats.overruns == 0 and stats.paced_s == pytest.approx(4 * 6e-4)  # none before 4


def test_steps_the_host_does_not_want_paced_run_back_to_back(clock) -> None:
    """GIVEN a host paced from its 4th step (booting before) WHEN looped THEN the first
    three steps are not waited for nor timed, the rest are."""
    host = _Host(clock, paced_from=3)
    stats = stepping.step_loop(host, until_s=0.006, pacer=WallPacer(1e-3, 0.02))
    assert len(stats.lateness_us) == 3
    assert host.starts[1] - host.starts[0] == pytest.approx(4e-4)


def test_a_stop_ends_the_loop_after_the_step_that_set_it(clock) -> None:
    """GIVEN a stop set by the host's 4th step WHEN looped without an end time THEN the
    loop ends after that step."""
    stop = threading.Event()
    host = _Host(clock, stop=stop, stop_at=4)
    stats = stepping.step_loop(host, stop, pacer=WallPacer(1e-3, 0.02))
    assert host.steps == stats.steps == 4

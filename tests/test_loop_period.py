"""Control-loop period watch: late cycles pause the estimator, a lasting overrun is flagged."""

import math

import numpy as np
import pytest

from companion.config import load_config
from companion.control.flight import FlightControl
from companion.control.laws import ControlRateError
from companion.mission.loop_period import CycleWindow, GapCause, GapTimes, LoopPeriodMonitor


def feed(monitor, times):
    return [monitor.update(t) for t in times]


def test_steady_cycles_are_on_time_and_no_overrun():
    monitor = LoopPeriodMonitor(0.004, 0.035)  # 1 s window
    out = feed(monitor, np.arange(0.0, 1.5, 0.004))
    assert out[0] is None
    assert not any(c.late for c in out[1:])
    assert monitor.mean_period_s == pytest.approx(0.004)
    assert not monitor.overrun and monitor.late_cycles == 0


def test_a_cycle_of_three_periods_is_late():
    monitor = LoopPeriodMonitor(0.004, 0.035)
    feed(monitor, 0.004 * np.arange(51))  # up to 0.2 s
    late = monitor.update(0.2 + 0.012)
    assert late.late and late.period_s == pytest.approx(0.012)
    assert not any(c.late for c in feed(monitor, 0.212 + 0.004 * np.arange(1, 10)))
    assert monitor.late_cycles == 1
    assert monitor.longest_period_s == pytest.approx(0.012)


def test_a_gap_of_two_periods_is_jitter_not_late():
    monitor = LoopPeriodMonitor(0.004, 0.035)
    feed(monitor, [0.0, 0.004])
    assert not monitor.update(0.012).late


def test_repeated_long_cycles_are_an_overrun():
    monitor = LoopPeriodMonitor(0.004, 0.035, window_s=1.0, overrun_cycles=3)
    feed(monitor, np.arange(0.0, 1.0, 0.004))
    slow = feed(monitor, 1.0 + 0.04 * np.arange(1, 3))  # two 40 ms cycles
    assert all(c.late for c in slow)
    assert not monitor.overrun and monitor.long_cycles == 2
    monitor.update(1.12)
    assert monitor.overrun and monitor.long_cycles == 3
    feed(monitor, 1.12 + 0.004 * np.arange(1, 300))  # back to 250 Hz for 1.2 s
    assert not monitor.overrun and monitor.long_cycles == 0


def test_a_starved_loop_with_bursts_is_an_overrun():
    monitor = LoopPeriodMonitor(0.004, 0.035)
    feed(monitor, np.arange(0.0, 1.0, 0.004))
    t = 1.0
    for _ in range(3):  # a 200 ms stall, then four queued poses 4 ms apart
        t += 0.2
        feed(monitor, t + 0.004 * np.arange(4))
        t += 0.012
    assert monitor.overrun


def test_one_long_stall_is_not_an_overrun():
    monitor = LoopPeriodMonitor(0.004, 0.035)
    feed(monitor, np.arange(0.0, 1.0, 0.004))
    stall = monitor.update(1.336)
    assert stall.late and monitor.long_cycles == 1
    feed(monitor, 1.336 + 0.004 * np.arange(1, 100))
    assert not monitor.overrun


def test_mean_period_is_nan_before_a_full_window():
    monitor = LoopPeriodMonitor(0.004, 0.035, window_s=0.5)
    feed(monitor, np.arange(0.0, 0.3, 0.004))
    assert math.isnan(monitor.mean_period_s) and not monitor.overrun


@pytest.mark.parametrize(
    "kwargs",
    [
        {"period_s": 0.0, "max_period_s": 0.01},
        {"period_s": 0.01, "max_period_s": 0.005},
        {"period_s": 0.004, "max_period_s": 0.01, "late_factor": 1.0},
        {"period_s": 0.004, "max_period_s": 0.01, "window_s": 0.0},
        {"period_s": 0.004, "max_period_s": 0.01, "overrun_cycles": 0},
    ],
)
def test_bad_parameters_are_refused(kwargs):
    with pytest.raises(ValueError):
        LoopPeriodMonitor(**kwargs)


def test_max_period_is_where_the_rate_check_starts_refusing():
    control = FlightControl(load_config("configs/sitl_pickup.toml"), "passivity")
    q = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -0.5 * math.pi])
    max_period_s = control.max_period_s(q)
    assert 0.004 < max_period_s < 1.0
    control.check_rate(1.0 / (0.99 * max_period_s), q)
    with pytest.raises(ControlRateError):
        control.check_rate(1.0 / (1.01 * max_period_s), q)


PERIOD_S = 0.008


@pytest.mark.parametrize(
    ("run_s", "cpu_wait_s", "socket_wait_s", "cause"),
    [
        # measured in demo flights with stalls injected into the companion:
        (0.0457, 0.0, 0.0344, GapCause.COMPANION),  # 40 ms of CPU in the control thread
        (0.0058, 0.0, 0.0445, GapCause.BLOCKED),  # a 50 ms sleep in it
        (0.0083, 0.1013, 0.0977, GapCause.HOST),  # a SCHED_FIFO 60 process on its CPU
        # and the edges:
        (0.020, 0.020, 0.050, GapCause.COMPANION),  # a tie goes against ourselves
        (0.001, 0.001, 0.0004, GapCause.ARRIVAL),  # nothing waited: the poses came late
        (0.004, 0.003, 0.012, GapCause.ARRIVAL),  # no share reaches a period
        (0.001, 0.009, None, GapCause.HOST),  # a serial link: the CPU wait still tells
        (0.001, 0.001, None, GapCause.UNKNOWN),
        (None, None, 0.047, GapCause.UNKNOWN),  # no scheduler accounting
    ],
)
def test_a_gap_is_blamed_on_who_held_it_up(run_s, cpu_wait_s, socket_wait_s, cause):
    assert GapTimes(run_s, cpu_wait_s, socket_wait_s).cause(PERIOD_S) is cause


def after(window, times, socket_wait_s):
    """Push one cycle's end and return the window's gap."""
    window.push(times, socket_wait_s)
    return window.gap()


def test_the_window_spans_the_last_two_cycles():
    """The cycle before the one that sees a drop may be the slow one: its time counts."""
    window = CycleWindow()
    assert after(window, (1.0, 5.0), 0.001) == GapTimes(0.0, 0.0, 0.001)
    window.push((1.060, 5.0), 0.002)  # a 60 ms cycle
    gap = after(window, (1.061, 5.047), 0.0)
    assert gap.run_s == pytest.approx(0.061) and gap.cpu_wait_s == pytest.approx(0.047)
    assert gap.socket_wait_s == 0.002 and gap.cause(PERIOD_S) is GapCause.COMPANION
    gap = after(window, (1.062, 5.047), 0.0)  # the slow cycle left the window
    assert gap.run_s == pytest.approx(0.002) and gap.cpu_wait_s == pytest.approx(0.047)
    assert gap.socket_wait_s == 0.0 and gap.cause(PERIOD_S) is GapCause.HOST
    assert after(window, (1.063, 5.047), 0.0).cause(PERIOD_S) is GapCause.ARRIVAL


def test_a_window_without_accounting_is_unknown():
    window = CycleWindow()
    window.push((1.0, 5.0), None)
    assert after(window, None, None) == GapTimes(None, None, None)
    window.push((1.1, 5.0), None)
    assert after(window, (1.2, 5.0), None).run_s is None  # the window starts at the None
    assert after(window, (1.3, 5.0), None).run_s == pytest.approx(0.2)

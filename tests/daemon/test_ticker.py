"""The fixed-rate loop timer: deadlines, overruns, statistics (with a fake clock)."""

from __future__ import annotations

import pytest

from legws_daemon.daemon.ticker import STALL_SECONDS, Ticker, stall_threshold


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.sleeps.append(s)
        self.t += s


def test_sleeps_to_the_next_deadline_and_counts_overruns() -> None:
    clock = FakeClock()
    t = Ticker(20.0, clock=clock, sleep=clock.sleep)
    for work in (0.01, 0.02, 0.08, 0.01):
        t.begin()
        clock.t += work
        t.end()
    assert t.ticks == 4
    assert t.overruns == 1
    # first two ticks sleep the rest of their period; after the overrun the schedule
    # re-anchors at the overrun's end instead of bunching ticks up
    assert abs(clock.sleeps[0] - 0.04) < 1e-9
    assert abs(clock.sleeps[1] - 0.03) < 1e-9
    assert abs(clock.sleeps[2] - 0.04) < 1e-9
    p50, p100 = t.percentiles(50, 100)
    assert abs(p100 - 0.08) < 1e-9
    assert 0.01 <= p50 <= 0.02
    assert t.last_duration is not None


def test_unpaced_never_sleeps_but_still_reports_overruns() -> None:
    clock = FakeClock()
    t = Ticker(100.0, paced=False, clock=clock, sleep=clock.sleep)
    for _ in range(5):
        t.begin()
        clock.t += 0.001
        t.end()
    assert clock.sleeps == []
    t.begin()
    clock.t += 0.5
    assert t.end() is True


def test_the_stall_threshold_is_ten_periods_and_half_a_second() -> None:
    assert stall_threshold(0.01) == STALL_SECONDS == 0.5  # 100 Hz
    assert stall_threshold(0.05) == pytest.approx(0.5)  # 20 Hz (the sawyer profile)
    assert stall_threshold(0.1) == pytest.approx(1.0)  # 10 Hz: ten periods


def run_tick(t: Ticker, clock: FakeClock, work: float = 0.001) -> float | None:
    """One tick as the daemon runs it: begin, a little work, standstill, end."""
    t.begin()
    clock.t += work / 2
    gap = t.standstill()
    clock.t += work / 2
    t.end()
    return gap


def test_a_pause_between_ticks_is_a_stall_and_no_overrun() -> None:
    clock = FakeClock()
    t = Ticker(100.0, clock=clock, sleep=clock.sleep)
    t.restart()
    assert [run_tick(t, clock) for _ in range(5)] == [None] * 5
    clock.t += 0.4  # a long pause, but under the threshold: the loop only ran late
    assert run_tick(t, clock) is None
    assert t.stalls == 0 and t.overruns == 1
    clock.t += 2.0  # SIGSTOP for 2 s while the loop slept
    gap = run_tick(t, clock)
    assert gap == pytest.approx(2.001, abs=1e-6)  # (the late tick before did not sleep)
    assert (t.stalls, t.last_stall, t.overruns) == (1, gap, 1)  # not an overrun too
    assert clock.sleeps[-1] == pytest.approx(0.01 - 0.0005)  # a full period from the resume
    assert [run_tick(t, clock) for _ in range(5)] == [None] * 5
    assert t.stalls == 1


def test_a_pause_inside_a_tick_is_a_stall_too() -> None:
    """Before the check: this tick's; after it: the next tick's."""
    clock = FakeClock()
    t = Ticker(20.0, paced=False, clock=clock, sleep=clock.sleep)
    t.restart()
    run_tick(t, clock)
    t.begin()
    clock.t += 0.6  # paused after the tick began, before the robot was read
    assert t.standstill() == pytest.approx(0.6005, abs=1e-6)
    assert t.end() is False  # the work counts from the resume
    t.begin()
    assert t.standstill() is None
    clock.t += 0.7  # paused after the check
    t.end()
    assert run_tick(t, clock) == pytest.approx(0.7005, abs=1e-6)
    assert t.stalls == 2
    t.restart()  # a new schedule starts afresh
    clock.t += 5.0
    assert run_tick(t, clock) is None

"""The fixed-rate loop timer: deadlines, overruns, statistics (with a fake clock)."""

from __future__ import annotations

from legws_daemon.daemon.ticker import Ticker


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

"""The daemon's one rate limit, on an injected clock (no sleeps)."""

from __future__ import annotations

from legws_daemon.daemon.throttle import Throttle


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_the_first_passes_then_one_per_interval() -> None:
    clock = Clock()
    throttle: Throttle[None] = Throttle(2.0, clock)
    assert throttle.attempt() == 0
    clock.t += 1.5
    assert throttle.attempt() is None
    clock.t += 0.5
    assert throttle.attempt() == 1  # one held back since the last pass
    assert throttle.attempt() is None


def test_held_back_occurrences_are_counted_until_the_next_pass() -> None:
    clock = Clock()
    throttle: Throttle[None] = Throttle(1.0, clock)
    assert throttle.attempt() == 0
    for _ in range(5):
        clock.t += 0.125
        assert throttle.attempt() is None
    clock.t += 0.375
    assert throttle.attempt() == 5
    clock.t += 1.0
    assert throttle.attempt() == 0  # the count starts again after a pass


def test_keys_are_limited_apart() -> None:
    clock = Clock()
    throttle: Throttle[str] = Throttle(1.0, clock)
    assert throttle.attempt("a") == 0
    assert throttle.attempt("b") == 0
    assert throttle.attempt("a") is None
    clock.t += 1.0
    assert throttle.attempt("a") == 1
    assert throttle.attempt("b") == 0


def test_force_passes_at_once_with_the_count() -> None:
    clock = Clock()
    throttle: Throttle[str] = Throttle(1.0, clock)
    assert throttle.attempt("operator") == 0
    assert throttle.attempt("operator") is None
    assert throttle.attempt("operator", force=True) == 1
    assert throttle.attempt("operator") is None  # the forced pass restarts the interval


def test_an_explicit_time_overrides_the_clock() -> None:
    clock = Clock()
    throttle: Throttle[None] = Throttle(1.0, clock)
    assert throttle.attempt(now=5.0) == 0
    assert throttle.attempt(now=5.5) is None
    assert throttle.attempt(now=6.0) == 1
    assert throttle.attempt() == 0  # the clock (100 s) is far past

"""Prints what the reliability fuzzers fed, how it was answered, and how long each test
took (the figures of docs/reliability.md)."""

from __future__ import annotations

import pytest

from tests.reliability.helpers import TALLIES

_DURATIONS: dict[str, float] = {}


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if report.when == "call" and "tests/reliability/" in report.nodeid:
        _DURATIONS[report.nodeid.split("::", 1)[1]] = report.duration


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if not TALLIES and not _DURATIONS:
        return
    terminalreporter.section("reliability: cases fed, and seconds per test")
    for name, tally in TALLIES.items():
        terminalreporter.write_line(tally.line(name))
    for test, seconds in sorted(_DURATIONS.items(), key=lambda kv: -kv[1]):
        terminalreporter.write_line(f"{seconds:7.1f} s  {test}")

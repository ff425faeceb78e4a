"""Test-wide set-up: library caches and analytics go to a temporary folder, never $HOME
(one per process: each pytest-xdist worker has its own), and Hypothesis checks no deadline."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, settings

_TMP = Path(tempfile.mkdtemp(prefix="legws-tests-"))
for var in ("XDG_CACHE_HOME", "XDG_CONFIG_HOME", "XDG_DATA_HOME"):
    os.environ[var] = str(_TMP / var.lower())
os.environ["MESA_SHADER_CACHE_DIR"] = str(_TMP / "mesa")
# the processes the tests start compile each module once, into the checkout's cache (as
# under ./dev), not from source at every start
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
os.environ.setdefault("PYTHONPYCACHEPREFIX", str(Path(__file__).parents[1] / ".cache" / "pycache"))
os.environ.setdefault("MPLCONFIGDIR", str(_TMP / "mpl"))
# Rerun sends no analytics when CI is set (and with its own switch off); tests never talk
# to the internet.
os.environ.setdefault("CI", "true")
os.environ["RERUN_TELEMETRY_ENABLED"] = "false"
# the headless Rerun viewer wants a private runtime folder (else it warns on every start)
(_TMP / "xdg-runtime").mkdir(mode=0o700)
os.environ["XDG_RUNTIME_DIR"] = str(_TMP / "xdg-runtime")

# Benchmarks measure speed, not property tests: Hypothesis's per-example deadline and its
# too-slow health check would fail a test on a busy machine, e.g. with parallel workers.
# Example counts are unchanged.
settings.register_profile("legws", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("legws")


# --- the reliability summary: what the fuzzers fed, how it was answered, seconds per test ------
# (the figures of docs/reliability.md). Here rather than in tests/reliability/: with
# pytest-xdist the controlling process loads only this conftest and prints the summary; each
# worker sends it the tallies of the fuzz tests it ran.
_DURATIONS: dict[str, float] = {}
_TALLIES_KEY = "legws_reliability_tallies"


def _tallies() -> dict[str, Any]:
    """This process's tallies (empty unless the reliability tests were imported here)."""
    helpers = sys.modules.get("tests.reliability.helpers")
    tallies: dict[str, Any] = getattr(helpers, "TALLIES", {})
    return tallies


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if report.when == "call" and "tests/reliability/" in report.nodeid:
        _DURATIONS[report.nodeid.split("::", 1)[1]] = report.duration


def pytest_sessionfinish(session: pytest.Session) -> None:
    output = getattr(session.config, "workeroutput", None)  # set on an xdist worker only
    if output is not None:
        output[_TALLIES_KEY] = {
            name: {k: dict(v) if isinstance(v, dict) else v for k, v in vars(t).items()}
            for name, t in _tallies().items()
        }


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node: Any, error: object) -> None:
    """On the xdist controller: add a finished worker's tallies to this process's."""
    sent = getattr(node, "workeroutput", {}).get(_TALLIES_KEY)
    if not sent:
        return
    from collections import Counter

    from tests.reliability.helpers import TALLIES, Tally

    for name, fields in sent.items():
        tally = TALLIES.setdefault(name, Tally())
        for k, v in fields.items():
            if isinstance(v, dict):
                getattr(tally, k).update(Counter(v))
            else:
                setattr(tally, k, getattr(tally, k) + v)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    tallies = _tallies()
    if not tallies and not _DURATIONS:
        return
    terminalreporter.section("reliability: cases fed, and seconds per test")
    for name, tally in tallies.items():
        terminalreporter.write_line(tally.line(name))
    for test, seconds in sorted(_DURATIONS.items(), key=lambda kv: -kv[1]):
        terminalreporter.write_line(f"{seconds:7.1f} s  {test}")


# --- scheduling: the long tests first ------------------------------------------------------
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The tests marked ``slow`` (real processes, long searches) first, on every worker.

    pytest-xdist's ``worksteal`` hands each of the ``n`` workers a contiguous block of the
    collection (``len // n`` items, the rest to the later ones) and an idle worker steals the
    back half of the longest queue. So each block begins with its share of the slow tests
    and is filled up with the quick ones: every worker starts on long tests and the quick
    ones, stolen from the back, even out the end — no worker is left running a long test
    alone. The shares are whole modules (their module-scoped fixtures, e.g. a planned task
    graph, are made once), the most slow tests first to the worker with the fewest so far.
    In one process: the slow ones first. The order is the same in every worker (pytest-xdist
    requires it)."""
    slow = [item for item in items if item.get_closest_marker("slow") is not None]
    quick = [item for item in items if item.get_closest_marker("slow") is None]
    workers = int(getattr(config, "workerinput", {}).get("workercount", 1))
    if workers <= 1:
        items[:] = slow + quick
        return
    modules: dict[str, list[pytest.Item]] = {}
    for item in slow:
        modules.setdefault(item.nodeid.split("::", 1)[0], []).append(item)
    shares: list[list[pytest.Item]] = [[] for _ in range(workers)]
    for group in sorted(modules.values(), key=len, reverse=True):  # (a stable sort)
        min(shares, key=len).extend(group)
    order: list[pytest.Item] = []
    left, at = len(items), 0
    for k in range(workers):
        size = left // (workers - k)  # the scheduler's first split (worksteal.check_schedule)
        share = shares[k]
        fill = max(size - len(share), 0)
        order += share + quick[at : at + fill]
        at += fill
        left -= size
    order += quick[at:]  # (only when the slow ones outnumber a block)
    assert len(order) == len(items)
    items[:] = order


def pytest_collection_finish(session: pytest.Session) -> None:
    """A real-time recording some tests read is started in the background as soon as they
    are selected (tests/cli/test_replay_recording.py): minutes of real time that occupy no
    worker."""
    module = "tests/cli/test_replay_recording.py::"
    if session.config.option.collectonly:
        return  # nothing runs
    if any(item.nodeid.startswith(module) for item in session.items):
        from tests.cli.test_replay_recording import begin_demo

        begin_demo()

"""The terminal log of ``legws daemon`` and ``legws operator calibrate``."""

from __future__ import annotations

import io
import logging
import sys
from collections.abc import Iterator

import pytest

from legws_daemon.telemetry.terminal_log import LOGGERS, log_to_terminal


@pytest.fixture(autouse=True)
def _restore_loggers() -> Iterator[None]:
    saved = {n: (list(logging.getLogger(n).handlers), logging.getLogger(n).level) for n in LOGGERS}
    yield
    for name, (handlers, level) in saved.items():
        logger = logging.getLogger(name)
        logger.handlers[:] = handlers
        logger.setLevel(level)


def test_records_go_to_the_stderr_of_the_moment_not_a_closed_stand_in(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # an in-process command (CliRunner) installs the log while stderr is its buffer, then
    # closes the buffer; the next record must not print "--- Logging error ---" anywhere
    stand_in = io.StringIO()
    monkeypatch.setattr(sys, "stderr", stand_in)
    log_to_terminal("legws daemon")
    logging.getLogger("legws.daemon").info("started")
    assert stand_in.getvalue() == "legws daemon: started\n"
    stand_in.close()
    later = io.StringIO()
    monkeypatch.setattr(sys, "stderr", later)
    logging.getLogger("legws.plan").warning("stage 2 not certified")
    logging.getLogger("legws_daemon.telemetry.rerun_log").info("recording closed")
    assert later.getvalue() == (
        "legws daemon: stage 2 not certified\nlegws daemon: recording closed\n"
    )


def test_a_library_info_record_stays_off_the_terminal(capsys: pytest.CaptureFixture[str]) -> None:
    log_to_terminal("legws daemon")
    logging.getLogger("fontTools.subset").info("%s pruned", "GSUB")
    logging.getLogger("legws.daemon").debug("below INFO")
    assert capsys.readouterr().err == ""


def test_installing_twice_prints_each_record_once_with_the_newest_prefix(
    capsys: pytest.CaptureFixture[str],
) -> None:
    log_to_terminal("legws daemon")
    log_to_terminal("legws calibrate")
    logging.getLogger("legws.daemon").info("target 3 of 20")
    assert capsys.readouterr().err == "legws calibrate: target 3 of 20\n"


def test_records_still_reach_the_root_handlers(caplog: pytest.LogCaptureFixture) -> None:
    log_to_terminal("legws daemon")
    with caplog.at_level(logging.INFO):
        logging.getLogger("legws.plan").info("planned")
    assert [r.getMessage() for r in caplog.records] == ["planned"]

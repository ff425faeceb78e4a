"""Telemetry of the daemon: rerun recordings (:mod:`.rerun_log`) and reading them back
(:mod:`.recording`)."""

from __future__ import annotations

import os

# Before rerun is imported (it reads RUST_LOG once): its file sink warns at every start
# that a file without a footer is being written — the daemon's choice, the footer is added
# at close (:mod:`.rrd_file`). Other warnings stay; a RUST_LOG set by the user wins.
os.environ.setdefault("RUST_LOG", "warn,re_log_encoding::rrd::file_sink=error")
# rerun writes its own lines in colour even into a pipe or a file; a NO_COLOR the user set
# wins
os.environ.setdefault("NO_COLOR", "1")

from legws_daemon.telemetry.rerun_log import RerunLog, commit_text, parse_target

__all__ = ["RerunLog", "commit_text", "parse_target"]

"""Telemetry of the daemon: rerun recordings (:mod:`.rerun_log`) and reading them back
(:mod:`.recording`)."""

from __future__ import annotations

from legws_daemon.telemetry.rerun_log import RerunLog, commit_text, parse_target

__all__ = ["RerunLog", "commit_text", "parse_target"]

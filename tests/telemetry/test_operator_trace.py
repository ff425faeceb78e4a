"""A teleoperation trace from a recording: completed decisions and calibration reaches are
segments, a cancelled or single-candidate decision is not."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.log_lines import reach_text, reached_text
from legws_daemon.telemetry.operator_trace import recorded_segments
from legws_daemon.telemetry.rerun_log import RerunLog, commit_text
from legws_daemon.telemetry.snapshot import TickSnapshot
from tests.telemetry.helpers import setup, straight_episode, tick_kwargs


def _ticks(log: RerunLog, ep, first: int, n: int, mode: str, stick: np.ndarray | None) -> None:
    for k in range(n):
        kwargs = tick_kwargs(ep, k, None)
        kwargs.update(mode=mode, joystick=stick)
        log.log_tick(TickSnapshot(first + k, (first + k) * 0.05, **kwargs))


def test_completed_decisions_and_calibration_reaches_are_segments(tmp_path: Path) -> None:
    ep = straight_episode("breakfast_easy", "banana")
    goal = ep.goals.positions[ep.goals.index("banana")]
    stick = np.array([0.3, -0.2, -0.5])
    path = tmp_path / "session.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, ep, "choose")
        _ticks(log, ep, 0, 3, "teleop", None)  # not steering yet: no input
        _ticks(log, ep, 3, 10, "teleop", stick)
        log.log_text(13, 0.65, "INFO", commit_text("banana", 0.93))
        _ticks(log, ep, 13, 5, "assist", None)
        log.log_text(
            18,
            0.9,
            "INFO",
            "stage_done stage=choose goal=banana action=pick ticks=18 cancelled=False",
        )
        # a wrong commit the operator cancelled, then the right one: only the second counts
        setup(log, ep, "again")
        _ticks(log, ep, 20, 4, "teleop", stick)
        log.log_text(24, 1.2, "INFO", commit_text("cereal_box", 0.91))
        log.log_text(26, 1.3, "INFO", "cancel reason=button goal=cereal_box phase=rise")
        _ticks(log, ep, 27, 6, "teleop", -stick)
        log.log_text(33, 1.65, "INFO", commit_text("banana", 0.92, how="confirmed"))
        log.log_text(
            40,
            2.0,
            "INFO",
            "stage_done stage=again goal=banana action=pick ticks=40 cancelled=False",
        )
        # a single candidate: no steering, no segment
        log.log_text(41, 2.05, "INFO", commit_text("banana", 1.0, how="single"))
        log.log_text(
            42,
            2.1,
            "INFO",
            "stage_done stage=again goal=banana action=place ticks=42 cancelled=False",
        )
        # a calibration reach
        log.log_text(50, 2.5, "INFO", reach_text(1, 20, (0.61, -0.12, 0.25)))
        _ticks(log, ep, 50, 7, "calibrate", stick)
        log.log_text(57, 2.85, "INFO", reached_text(1))
    segments = recorded_segments(path)
    assert [s.ticks for s in segments] == [13, 6, 7]
    first, second, reach = segments
    np.testing.assert_allclose(first.goal, goal)
    assert np.all(first.u[:3] == 0.0)  # ticks without input are still
    np.testing.assert_allclose(first.u[3:], np.tile(stick, (10, 1)))
    np.testing.assert_allclose(second.u, np.tile(-stick, (6, 1)))
    np.testing.assert_allclose(reach.goal, [0.61, -0.12, 0.25])
    assert [s.label for s in segments] == [0, 1, 2]


def test_a_recording_without_a_known_goal_is_one_line(tmp_path: Path) -> None:
    ep = straight_episode("breakfast_easy", "banana")
    path = tmp_path / "idle.rrd"
    with RerunLog(f"save:{path}", robot="r") as log:
        setup(log, ep, "choose")
        _ticks(log, ep, 0, 5, "teleop", np.array([0.1, 0.0, 0.0]))
    with pytest.raises(InputError, match="no segment whose goal is known"):
        recorded_segments(path)

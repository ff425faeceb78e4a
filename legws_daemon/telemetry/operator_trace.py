"""A teleoperation trace (method.md §10, interfaces.md) from a daemon recording: the
segments whose goal is known.

* **A decision that completed**: the stage's commit (inferred or confirmed by the operator;
  a single candidate is no steering) followed by its ``stage_done`` without a cancel. Its
  segment is the stage's teleoperation ticks from the (re)start of inference — the stage's
  first tick, or the tick after its last cancel — up to the commit, toward the committed
  goal's position. A wrong commit that the operator cancelled is never a segment.
* **A calibration reach** (``legws operator calibrate``): the ticks from its ``calibration
  reach=i ... target=x,y,z`` line to its ``calibration reach=i done`` line, toward the target.

Every tick's EE position, deflection (zero on a tick without input: the robot stood still)
and mode come from the EE pose entity (:func:`~.recording.read_teleoperation`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.formats.log_lines import parse_commit, parse_reach
from legws_daemon.formats.trace import Segment
from legws_daemon.telemetry.recording import (
    Teleoperation,
    read_stages,
    read_teleoperation,
    read_text_lines,
)

#: The modes in which the operator steers the EE themselves.
TELEOP = "teleop"
CALIBRATE = "calibrate"


@dataclass
class _Open:
    stage: int
    start: int
    goal: str | None = None
    commit: int | None = None


def recorded_segments(path: Path | str) -> list[Segment]:
    """The segments of a recording, in the order they happened.

    Raises:
        InputError: naming the file, when it holds no teleoperation (recorded by a legws
            older than the deflection log) or no segment whose goal is known.
    """
    p = Path(path)
    tele = read_teleoperation(p)
    if not len(tele.ticks):
        raise InputError(
            "holds no teleoperation ticks with their deflection (recorded by an older legws?)",
            source=str(p),
        )
    stages = {s.index: s for s in read_stages(p)}
    out: list[tuple[int, Segment]] = []
    open_: _Open | None = None
    reach: tuple[int, int, FloatArray] | None = None  # (index, first tick, target)
    for tick, stage, text in read_text_lines(p):
        calibration = parse_reach(text)
        if calibration is not None:
            if calibration.target is not None:
                reach = (calibration.reach, tick, np.array(calibration.target))
            elif reach is not None and reach[0] == calibration.reach:
                seg = _segment(tele, CALIBRATE, reach[1], tick, None, reach[2], len(out))
                if seg is not None:
                    out.append((reach[1], seg))
                reach = None
            continue
        if stage is None:
            continue
        if open_ is None or open_.stage != stage:
            open_ = _Open(stage, _first_tick(tele, stage))
        commit = parse_commit(text)
        if commit is not None:
            if commit.how != "single":
                open_.goal, open_.commit = commit.goal, tick
            continue
        if text.startswith("cancel "):
            open_ = _Open(stage, tick + 1)
        elif text.startswith("stage_done ") and open_.commit is not None:
            fields = dict(part.split("=", 1) for part in text.split()[1:] if "=" in part)
            goals = stages[stage].goals if stage in stages else None
            done = fields.get("goal") == open_.goal and fields.get("cancelled") != "True"
            if done and goals is not None and open_.goal in goals.names:
                target = goals.positions[goals.index(open_.goal)]
                seg = _segment(tele, TELEOP, open_.start, open_.commit, stage, target, len(out))
                if seg is not None:
                    out.append((open_.start, seg))
            open_ = _Open(stage, tick + 1)
    if not out:
        raise InputError(
            "holds no segment whose goal is known (no decision that completed after a commit "
            "and no calibration reach)",
            source=str(p),
        )
    out.sort(key=lambda item: item[0])
    return [Segment(i, s.ee, s.u, s.goal, s.source) for i, (_, s) in enumerate(out)]


def _first_tick(tele: Teleoperation, stage: int) -> int:
    ticks = tele.ticks[tele.stages == stage]
    return int(ticks.min()) if len(ticks) else 0


def _segment(
    tele: Teleoperation,
    mode: str,
    start: int,
    end: int,
    stage: int | None,
    goal: FloatArray,
    label: int,
) -> Segment | None:
    """The ticks ``start <= tick < end`` in ``mode`` (of ``stage``), or ``None``."""
    pick = (tele.ticks >= start) & (tele.ticks < end)
    pick &= np.array([m == mode for m in tele.modes], dtype=bool)
    if stage is not None:
        pick &= tele.stages == stage
    if not pick.any():
        return None
    u = np.nan_to_num(tele.deflections[pick], nan=0.0)
    return Segment(label, tele.positions[pick], u, np.asarray(goal, dtype=np.float64),
                   f"ticks {start}..{end - 1}")  # fmt: skip

"""The text-log line of a commit, written by the daemon and read back by ``legws replay``.

``commit goal=<name> p=<prob>``, then `` how=confirmed`` when the operator pressed
*confirm*, or `` how=single`` when the stage had one candidate (no inference). The same
line is the daemon's log line and its Rerun text-log row.
"""

from __future__ import annotations

import math
import re
from typing import Literal, NamedTuple

How = Literal["inferred", "confirmed", "single"]

_COMMIT = re.compile(r"^commit goal=(?P<goal>.+?) p=(?P<p>\S+)(?: how=(?P<how>confirmed|single))?$")


class CommitLine(NamedTuple):
    goal: str
    p: float
    how: How


def commit_text(goal: str, p: float, *, how: How = "inferred") -> str:
    """The line of a commit (``p`` as Python prints the float: ``0.9004``)."""
    line = f"commit goal={goal} p={float(p)}"
    return line if how == "inferred" else f"{line} how={how}"


def parse_commit(text: str) -> CommitLine | None:
    """The commit of a text-log line, else ``None`` (also for a non-finite ``p``)."""
    match = _COMMIT.match(text)
    if match is None:
        return None
    try:
        p = float(match["p"])
    except ValueError:
        return None
    how: How = match["how"] or "inferred"  # type: ignore[assignment]
    return CommitLine(match["goal"], p, how) if math.isfinite(p) else None


# --- calibration (legws operator calibrate, method.md §10) ---------------------------------

# at most 9 digits: an index a line of any length can hold stays an ordinary integer
_REACH = re.compile(
    r"^calibration reach=(?P<i>\d{1,9}) of=(?P<n>\d{1,9}) "
    r"target=(?P<x>\S{1,64}),(?P<y>\S{1,64}),(?P<z>\S{1,64})$"
)
_REACHED = re.compile(r"^calibration reach=(?P<i>\d{1,9}) done$")


class ReachLine(NamedTuple):
    """A calibration reach begins (``target`` set) or ends (``target`` ``None``)."""

    reach: int
    of: int | None
    target: tuple[float, float, float] | None


def reach_text(index: int, of: int, target: tuple[float, float, float]) -> str:
    """The line of a reach's start: ``calibration reach=3 of=20 target=0.61,-0.12,0.25``
    (0.1 mm)."""
    x, y, z = (f"{float(v):.4f}" for v in target)
    return f"calibration reach={index} of={of} target={x},{y},{z}"


def reached_text(index: int) -> str:
    """The line of a reach's end (the EE arrived at its target)."""
    return f"calibration reach={index} done"


def parse_reach(text: str) -> ReachLine | None:
    """The calibration reach a text-log line begins or ends, else ``None``."""
    done = _REACHED.match(text)
    if done is not None:
        return ReachLine(int(done["i"]), None, None)
    match = _REACH.match(text)
    if match is None:
        return None
    try:
        target = (float(match["x"]), float(match["y"]), float(match["z"]))
    except ValueError:
        return None
    if not all(math.isfinite(v) and abs(v) <= 100.0 for v in target):
        return None
    return ReachLine(int(match["i"]), int(match["n"]), target)

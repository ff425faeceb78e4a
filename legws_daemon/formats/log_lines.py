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

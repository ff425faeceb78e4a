"""Teleoperation traces (interfaces.md, method.md §10): JSON Lines, one control tick a line.

```json
{"segment": 0, "ee": [0.55, 0.0, 0.30], "u": [0.41, 0.12, -0.80], "goal": [0.62, 0.21, 0.07]}
```

``segment``: an integer, the same for one reach toward one goal (its lines consecutive);
``ee``: the EE position at the tick (m, base frame); ``u``: the deflection sent at that tick
(norm at most 1); ``goal``: the goal's position, the same on every line of a segment. Extra
fields are kept out of the way (allowed, not read). Lines are read one at a time (a large
trace never sits in memory as text); every error is one line naming the file, the line and
the field (``trace.jsonl:2: u: ...``). Written by ``legws operator trace`` (from a
recording) and ``legws operator calibrate``, read by ``legws operator fit``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.formats.files import open_output, read_lines
from legws_daemon.formats.nesting import check_json_nesting
from legws_daemon.formats.validation import (
    MAX_COORDINATE,
    DuplicateKeyError,
    check_json_text,
    printable,
    unique_keys,
)

#: A deflection may exceed norm 1 by this much (rounding in the sender's own clip).
NORM_TOLERANCE = 1e-6
#: Most segments and ticks in one trace: a calibration has 20 reaches of a few hundred
#: ticks; the size limit of a trace file (32 MiB) holds about 250,000.
MAX_SEGMENTS = 100_000
MAX_TICKS = 5_000_000


@dataclass(frozen=True, slots=True)
class Segment:
    """One reach toward one goal: ``ee`` and ``u`` ``(n, 3)`` per tick, ``goal`` ``(3,)``.

    Attributes:
        label: the segment's number in its trace.
        source: where it came from (``FILE:LINE`` of its first tick).
    """

    label: int
    ee: FloatArray
    u: FloatArray
    goal: FloatArray
    source: str = ""

    @property
    def ticks(self) -> int:
        return len(self.ee)


def _vector(value: Any, where: str, field: str, bound: float) -> list[float]:
    ok = (
        isinstance(value, list)
        and len(value) == 3
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    )
    if not ok:
        raise InputError(f"expected three numbers, got {_short(value)}", source=where, field=field)
    out = [float(v) for v in value]
    if not all(math.isfinite(v) and abs(v) <= bound for v in out):
        raise InputError(
            f"expected finite numbers within ±{bound:g}, got {_short(value)}",
            source=where,
            field=field,
        )
    return out


def _short(value: Any) -> str:
    text = printable(repr(value))
    return text if len(text) <= 60 else text[:57] + "..."


def parse_tick(text: str, where: str) -> tuple[int, list[float], list[float], list[float]]:
    """``(segment, ee, u, goal)`` of one line; ``where`` is ``FILE:LINE``."""
    check_json_nesting(text, where)
    try:
        data = json.loads(text, object_pairs_hook=unique_keys)
    except DuplicateKeyError as dup:
        raise InputError(
            f"the key {printable(dup.key)!r} appears twice", source=where, field=dup.key
        ) from None
    except (json.JSONDecodeError, RecursionError, ValueError) as err:
        reason = err.msg if isinstance(err, json.JSONDecodeError) else "not valid JSON"
        raise InputError(f"invalid JSON: {reason}", source=where) from None
    if not isinstance(data, dict):
        raise InputError(f"expected a JSON object, got {_short(data)}", source=where)
    check_json_text(data, text, where)
    for key in ("segment", "ee", "u", "goal"):
        if key not in data:
            raise InputError("missing", source=where, field=key)
    segment = data["segment"]
    if not isinstance(segment, int) or isinstance(segment, bool) or not 0 <= segment < 2**63:
        raise InputError(
            f"expected an integer >= 0, got {_short(segment)}", source=where, field="segment"
        )
    ee = _vector(data["ee"], where, "ee", MAX_COORDINATE)
    u = _vector(data["u"], where, "u", 1.0 + NORM_TOLERANCE)
    if math.hypot(*u) > 1.0 + NORM_TOLERANCE:
        raise InputError(
            f"a deflection has norm at most 1, got {math.hypot(*u):.6g}", source=where, field="u"
        )
    goal = _vector(data["goal"], where, "goal", MAX_COORDINATE)
    return segment, ee, u, goal


def read_trace(path: Path) -> list[Segment]:
    """The segments of a trace file, in the order they start.

    Raises:
        InputError: one line naming the file, the line and the field: a line that is not a
            tick, a segment whose lines are not consecutive or whose goal changes, an empty
            trace, more than :data:`MAX_SEGMENTS` segments or :data:`MAX_TICKS` ticks.
    """
    return list(_segments(Path(path), read_lines(path, "teleoperation trace")))


def _segments(path: Path, lines: Iterable[tuple[int, str]]) -> Iterator[Segment]:
    seen: set[int] = set()
    current: tuple[int, list[float], str] | None = None
    ee: list[list[float]] = []
    u: list[list[float]] = []
    ticks = 0
    for number, text in lines:
        if not text.strip():
            continue
        where = f"{path}:{number}"
        segment, e, d, goal = parse_tick(text, where)
        ticks += 1
        if ticks > MAX_TICKS:
            raise InputError(f"more than {MAX_TICKS:,} ticks", source=where)
        if current is None or segment != current[0]:
            if segment in seen:
                raise InputError(
                    f"segment {segment} started earlier: a segment's lines must be consecutive",
                    source=where,
                    field="segment",
                )
            if current is not None:
                yield _segment(current, ee, u)
            if len(seen) >= MAX_SEGMENTS:
                raise InputError(f"more than {MAX_SEGMENTS:,} segments", source=where)
            seen.add(segment)
            current, ee, u = (segment, goal, where), [], []
        elif goal != current[1]:
            raise InputError(
                f"segment {segment} changed its goal from {current[1]} (its first line)",
                source=where,
                field="goal",
            )
        ee.append(e)
        u.append(d)
    if current is None:
        raise InputError("no ticks: the trace is empty", source=str(path))
    yield _segment(current, ee, u)


def _segment(
    head: tuple[int, list[float], str], ee: list[list[float]], u: list[list[float]]
) -> Segment:
    label, goal, where = head
    return Segment(label, np.array(ee), np.array(u), np.array(goal), where)


def tick_line(segment: int, ee: ArrayLike, u: ArrayLike, goal: ArrayLike) -> str:
    """One tick as a trace line (rounded to 0.1 µm and 1e-6 of a deflection)."""
    data = {
        "segment": int(segment),
        "ee": [round(float(v), 7) for v in np.asarray(ee).ravel()],
        "u": [round(float(v), 6) for v in np.asarray(u).ravel()],
        "goal": [round(float(v), 7) for v in np.asarray(goal).ravel()],
    }
    return json.dumps(data, separators=(", ", ": "))


def write_trace(path: Path, segments: Iterable[Segment]) -> int:
    """Write ``segments`` as a trace file (whole lines only, even on a full disk); returns
    the number of ticks written."""
    n = 0
    with open_output(Path(path)) as out:
        for seg in segments:
            lines = [
                tick_line(seg.label, e, d, seg.goal) for e, d in zip(seg.ee, seg.u, strict=True)
            ]
            out.write("".join(line + "\n" for line in lines))
            n += len(lines)
    return n

"""Number options of the command line: finite, within their range, or one-line errors."""

from __future__ import annotations

import math
import re
from typing import Any

import click


class FiniteFloat(click.FloatRange):
    """A :class:`click.FloatRange` that also refuses ``nan`` and ``inf`` (click accepts
    both: NaN passes every comparison, and an open-ended range takes infinity)."""

    name = "float"

    def _describe_range(self) -> str:
        """The range for the help text; nothing for an unbounded one (click would say
        ``x<=None``)."""
        if self.min is None and self.max is None:
            return ""
        return str(super()._describe_range())

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return number


class PixelSize(click.ParamType[tuple[int, int]]):
    """``WIDTHxHEIGHT`` in pixels (``800x500``), each side within ``min_side..max_side``."""

    name = "WIDTHxHEIGHT"

    def __init__(self, min_side: int, max_side: int) -> None:
        self.min_side, self.max_side = min_side, max_side

    def convert(
        self, value: Any, param: click.Parameter | None, ctx: click.Context | None
    ) -> tuple[int, int]:
        if isinstance(value, tuple):
            return value  # a default given as a pair
        match = re.fullmatch(r"\s*(\d{1,5})\s*[xX]\s*(\d{1,5})\s*", str(value))
        if not match:
            self.fail(f"expected WIDTHxHEIGHT in pixels, e.g. 1600x1000, got {value!r}", param, ctx)
        width, height = int(match[1]), int(match[2])
        lo, hi = self.min_side, self.max_side
        if not (lo <= width <= hi and lo <= height <= hi):
            self.fail(f"expected {lo}-{hi} pixels a side, got {value!r}", param, ctx)
        return width, height

"""Number options of the command line: finite, within their range, or one-line errors."""

from __future__ import annotations

import math
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

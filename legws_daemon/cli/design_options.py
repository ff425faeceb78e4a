"""Options ``legws optimize`` and ``legws plan`` share: what the layout search optimises."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import click

from legws_daemon.core.commit import COMMIT_FORMS
from legws_daemon.design import OBJECTIVES

R = TypeVar("R")


def objective_options(per: str = "") -> Callable[[Callable[..., R]], Callable[..., R]]:
    """``--objective`` (passed as ``objective_kind``) and ``--commit-form``; ``per``
    prefixes the help (``"Per decision: "`` for plans)."""

    def decorate(f: Callable[..., R]) -> Callable[..., R]:
        f = click.option(
            "--commit-form", type=click.Choice(COMMIT_FORMS), default="sum", show_default=True,
            help="With --objective commit: K of the exact-sum commit slack or of §9's even "
            "split.",
        )(f)  # fmt: skip
        return click.option(
            "--objective", "objective_kind", type=click.Choice(OBJECTIVES), default="slack",
            show_default=True,
            help=f"{per}{'m' if per else 'M'}aximise the slack J (method.md §4); certify "
            "early commits: minimise K (§9); maximise the estimated commit rate R over all "
            "goals (where K cannot reach 1); or minimise the estimated commit time T (s).",
        )(f)  # fmt: skip

    return decorate

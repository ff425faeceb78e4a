"""Options ``legws optimize`` and ``legws plan`` share: what the layout search optimises, and
for whom."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import click

from legws_daemon.core.commit import COMMIT_FORMS
from legws_daemon.design import OBJECTIVES
from legws_daemon.errors import InputError
from legws_daemon.formats.operator_file import OperatorFile, load_operator

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


def operator_options(per: str = "") -> Callable[[Callable[..., R]], Callable[..., R]]:
    """``--operator FILE`` (passed as ``operator_file``) and ``--operators A,B,...``
    (``operator_files``): design for one person, or for the worst of a group (method.md
    §10, with the robot's clip); ``per`` prefixes the help."""

    def decorate(f: Callable[..., R]) -> Callable[..., R]:
        f = click.option(
            "--operators", "operator_files", metavar="A.json,B.json",
            help=f"{per}design for the worst of a group: comma-separated operator files "
            "(J the smallest, K and T the largest, R the smallest over them).",
        )(f)  # fmt: skip
        return click.option(
            "--operator", "operator_file", type=click.Path(path_type=Path, dir_okay=False),
            help=f"{per}design for one person: an operator file (legws operator fit); every "
            "searched score is that person's certify_with model with the robot's clip.",
        )(f)  # fmt: skip

    return decorate


def load_operators(
    operator_file: Path | None, operator_files: str | None
) -> tuple[OperatorFile, ...]:
    """The operator files of ``--operator`` or ``--operators`` (``()`` for neither), each
    validated (one line naming the file and the field).

    Raises:
        InputError: both options, an empty list, a name given twice, or a bad file.
    """
    if operator_file is not None and operator_files is not None:
        raise InputError("give --operator or --operators, not both", field="--operators")
    if operator_file is not None:
        return (load_operator(operator_file),)
    if operator_files is None:
        return ()
    paths = [p.strip() for p in operator_files.split(",") if p.strip()]
    if not paths:
        raise InputError("expected comma-separated operator files", field="--operators")
    files = tuple(load_operator(Path(p)) for p in paths)
    names = [f.name for f in files]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InputError(f"operator {twice[0]!r} is given twice", field="--operators")
    return files

"""``--robot``: the arm a command is for (a registered name, :mod:`legws_daemon.arms`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import click

from legws_daemon.arms import arm_names

F = TypeVar("F", bound=Callable[..., Any])


def robot_option(default: str | None = None, what: str = "the arm") -> Callable[[F], F]:
    """The ``--robot NAME`` option (``default`` None: the profile's ``arm``)."""
    help_text = f"The arm ({', '.join(arm_names())}): {what}" + (
        "." if default is not None else "; default the profile's `arm` (the Sawyer)."
    )
    return click.option(
        "--robot",
        "robot",
        type=click.Choice(arm_names()),
        default=default,
        show_default=default is not None,
        help=help_text,
    )

"""``--robot``: the arm a command is for (a registered name, :mod:`legws_daemon.arms`); and
the real arm's two permissions of a command that runs the daemon itself."""

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


def real_arm_options() -> Callable[[F], F]:
    """``--allow-motion`` and ``--insecure-transport``, as ``legws daemon`` takes them, for a
    command that runs the daemon (or daemons) itself."""
    allow = click.option(
        "--allow-motion",
        is_flag=True,
        help="Required for a profile that drives real hardware, as for `legws daemon`.",
    )
    insecure = click.option(
        "--insecure-transport",
        is_flag=True,
        help="Let a real arm run on an unauthenticated transport, as for `legws daemon`.",
    )

    def both(f: F) -> F:
        return allow(insecure(f))

    return both

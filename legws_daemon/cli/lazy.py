"""A click group that imports its commands' modules on first use.

``legws`` has twenty commands over the optimiser, the renderer, rerun, MuJoCo and zenoh; a
command's process loads only what that command needs (a publisher starts in a fraction of
the time, and so does every process a test or a lab script spawns).
"""

from __future__ import annotations

import importlib
from typing import Any

import click

__all__ = ["LazyGroup"]


class LazyGroup(click.Group):
    """A group whose commands are imported by name, on first use (click's lazy-loading
    pattern). A command added with :meth:`add_command` takes precedence over the table."""

    def __init__(self, *args: Any, lazy: dict[str, str], **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._lazy = lazy

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*self._lazy, *self.commands})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in self.commands:
            return self.commands[cmd_name]
        where = self._lazy.get(cmd_name)
        if where is None:
            return None
        module_name, attribute = where.split(":")
        command = getattr(importlib.import_module(module_name), attribute)
        if not isinstance(command, click.Command):
            raise TypeError(f"{where} is not a click command")
        self.commands[cmd_name] = command
        return command

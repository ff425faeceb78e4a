"""The command router's parts: where each command on the command key is carried out, and a
command on its way from the query to its reply.

Every command the messages accept (:class:`~legws_daemon.formats.messages.CommandRequest`'s
``command`` and ``hello``) has one :class:`Route`: answered on the zenoh thread at once
(``status``, ``hello``: nothing the robot does depends on them), carried out by the control
loop between ticks (``stop``, ``reset``, ``release``, ``take_control``), or prepared off the
loop and installed by it (``load_scene``, ``load_taskgraph``: :mod:`.loads`). A route holds
its handler, whether it cancels the loads asked before it (a load must not undo a stop), and
the daemon's table (:data:`legws_daemon.daemon.service.ROUTES`) is checked against the
message's commands when it is built (:func:`check_routes`): a command added to the message
without a route, or a route without its handler, fails at import, not on the robot.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, Generic, TypeVar, get_args

from legws_daemon.formats.messages import CommandRequest, HelloRequest

S = TypeVar("S")
#: A request on the command key, parsed once.
Request = CommandRequest | HelloRequest


class Where(StrEnum):
    """Where a command is carried out."""

    AT_ONCE = "at once"  # on the zenoh thread that received it
    LOOP = "loop"  # by the control loop, between ticks
    LOAD = "load"  # prepared off the loop, installed by it (:mod:`.loads`)


@dataclass(frozen=True)
class Route(Generic[S]):
    """One command's way through the daemon ``S``.

    ``answer(service, query, request)`` replies on the zenoh thread (:attr:`Where.AT_ONCE`);
    ``run(service, request, now)`` carries it out on the loop and returns the reply's
    detail (:attr:`Where.LOOP`; a :class:`~legws_daemon.errors.LegwsError` it raises is the
    reply's ``error``); a load has neither (the pipeline prepares and installs it).
    """

    where: Where
    answer: Callable[[S, Any, Request], None] | None = None
    run: Callable[[S, CommandRequest, float], dict[str, Any]] | None = None
    #: the loads asked before it are cancelled, answered with why (``stop``)
    cancels_loads: bool = False


def commands() -> frozenset[str]:
    """Every command the command key accepts (the messages' own list)."""
    literal = CommandRequest.model_fields["command"].annotation
    hello = HelloRequest.model_fields["command"].annotation
    return frozenset(get_args(literal)) | frozenset(get_args(hello))


def check_routes(routes: Mapping[str, Route[Any]]) -> None:
    """Raise :class:`TypeError` unless ``routes`` has exactly one route per command and
    each route the handler its place needs."""
    known = commands()
    if set(routes) != known:
        missing, extra = sorted(known - set(routes)), sorted(set(routes) - known)
        raise TypeError(f"command routes: missing {missing}, unknown {extra}")
    for name, route in routes.items():
        wants = (route.where == Where.AT_ONCE, route.where == Where.LOOP)
        has = (route.answer is not None, route.run is not None)
        if wants != has:
            raise TypeError(f"command route {name!r} ({route.where}): handlers {has}")


@dataclass
class PendingCommand:
    """A command on its way from the query to the loop; :meth:`finish` replies (once)."""

    request: CommandRequest
    respond: Callable[[dict[str, Any]], None]
    arrived: float = field(default_factory=time.monotonic)
    answered: bool = False

    def finish(self, reply: dict[str, Any]) -> None:
        if not self.answered:
            self.answered = True
            self.respond(reply)

    def fail(self, error: str) -> None:
        """Reply that it was not done, and why."""
        self.finish({"ok": False, "command": self.request.command, "error": error})

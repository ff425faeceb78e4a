"""The command router's table and the load pipeline, without zenoh: every command has one
route with the handler its place needs, and loads are prepared one at a time, in order,
answered once (busy, cancelled, failed or installed), and freed off the loop."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any, cast

import pytest

from legws_daemon.autonomy.controller import LOADS, PreparedLoad
from legws_daemon.daemon.commands import PendingCommand, Route, Where, check_routes, commands
from legws_daemon.daemon.loads import LOAD_QUEUE, LoadPipeline
from legws_daemon.daemon.service import ROUTES
from legws_daemon.errors import InputError
from legws_daemon.formats.messages import CommandRequest


def test_every_command_of_the_messages_has_one_route() -> None:
    assert set(ROUTES) == commands()
    assert {"hello", "status", "stop", "reset", "load_scene"} <= commands()
    assert {n for n, r in ROUTES.items() if r.where == Where.LOAD} == LOADS
    assert {n for n, r in ROUTES.items() if r.cancels_loads} == {"stop"}
    # nothing that moves the robot or changes the lease is answered off the loop
    assert {n for n, r in ROUTES.items() if r.where == Where.AT_ONCE} == {"hello", "status"}


def test_a_missing_or_unknown_command_or_a_handler_out_of_place_fails_the_check() -> None:
    routes: dict[str, Route[Any]] = dict(ROUTES)
    del routes["reset"]
    with pytest.raises(TypeError, match=r"missing \['reset'\]"):
        check_routes(routes)
    with pytest.raises(TypeError, match=r"unknown \['dance'\]"):
        check_routes({**ROUTES, "dance": Route(Where.LOOP, run=lambda s, r, t: {})})
    with pytest.raises(TypeError, match="'stop'"):
        check_routes({**ROUTES, "stop": Route(Where.LOOP)})  # no handler
    with pytest.raises(TypeError, match="'status'"):
        check_routes({**ROUTES, "status": Route(Where.AT_ONCE, run=lambda s, r, t: {})})


@dataclass
class Prepared:
    """What the pipeline sees of a prepared load: its name, and whether it was freed."""

    name: str
    discarded: bool = False

    def discard(self) -> None:
        self.discarded = True


@dataclass
class Bench:
    """A pipeline whose preparation the test releases, load by load."""

    release: dict[str, threading.Event] = field(default_factory=dict)
    prepared: list[str] = field(default_factory=list)
    installed: list[str] = field(default_factory=list)
    disposed: list[str] = field(default_factory=list)
    replies: list[tuple[str, dict[str, Any]]] = field(default_factory=list)
    failing: set[str] = field(default_factory=set)
    refused: set[str] = field(default_factory=set)

    def __post_init__(self) -> None:
        self.pipe = LoadPipeline(self.prepare, self.install, self.dispose)

    def prepare(self, request: CommandRequest) -> PreparedLoad:
        name = str(request.argument)
        self.release.setdefault(name, threading.Event()).wait(10.0)
        self.prepared.append(name)
        if name in self.failing:
            raise InputError(f"no scene {name!r}")
        return cast(PreparedLoad, Prepared(name))

    def install(self, prepared: PreparedLoad) -> tuple[dict[str, Any], Any]:
        name = cast(Prepared, prepared).name
        if name in self.refused:
            raise InputError("the robot is calibrating")
        self.installed.append(name)
        return {"scene": name}, f"old-of-{name}"

    def dispose(self, old: Any) -> None:
        self.disposed.append(str(old))

    def ask(self, name: str) -> PendingCommand:
        request = CommandRequest.model_validate(
            {"schema": 1, "command": "load_scene", "argument": name}
        )
        pending = PendingCommand(request, lambda reply: self.replies.append((name, reply)))
        self.pipe.offer(pending)
        return pending

    def tick(self) -> int:
        """One tick: install what finished, then the after-tick hand-over."""
        n = self.pipe.install_finished()
        self.pipe.hand_over()
        return n

    def finish(self, name: str) -> None:
        """Let ``name``'s preparation end and tick until it is installed (or answered)."""
        self.release.setdefault(name, threading.Event()).set()
        for _ in range(2000):
            if self.tick():
                return
            threading.Event().wait(0.002)
        raise AssertionError(f"{name} never finished")

    def settle(self) -> None:
        """The preparer's queued work (frees) done: a marker handed over after it ran."""
        done = threading.Event()
        self.pipe.off_loop(done.set)
        self.pipe.hand_over()
        assert done.wait(10.0)


def test_loads_are_prepared_one_at_a_time_in_order_and_each_answered_once() -> None:
    b = Bench()
    for name in ("a", "b", "c"):
        b.ask(name)
    b.tick()  # the hand-over starts "a" only
    for name in ("c", "b"):
        b.release.setdefault(name, threading.Event()).set()  # out of order: still in order
    b.finish("a")
    b.finish("b")
    b.finish("c")
    b.settle()
    assert b.prepared == b.installed == ["a", "b", "c"]
    assert [n for n, _ in b.replies] == ["a", "b", "c"]
    assert all(r["ok"] and r["command"] == "load_scene" for _, r in b.replies)
    assert sorted(b.disposed) == ["old-of-a", "old-of-b", "old-of-c"]  # freed off the loop


def test_more_than_the_queue_are_busy_and_a_cancel_answers_every_load_not_installed() -> None:
    b = Bench()
    b.ask("first")
    b.tick()  # "first" is being prepared
    for i in range(LOAD_QUEUE + 2):
        b.ask(f"w{i}")
    busy = [n for n, r in b.replies if "busy" in r.get("error", "")]
    assert busy == [f"w{LOAD_QUEUE}", f"w{LOAD_QUEUE + 1}"]
    b.pipe.cancel("cancelled: a stop came after it")
    cancelled = [n for n, r in b.replies if r.get("error") == "cancelled: a stop came after it"]
    assert cancelled == [*(f"w{i}" for i in range(LOAD_QUEUE)), "first"]
    b.release.setdefault("first", threading.Event()).set()
    for _ in range(2000):
        if b.tick():
            break
        threading.Event().wait(0.002)
    b.settle()
    assert b.installed == []  # the cancelled load was prepared but never installed
    assert len(b.replies) == LOAD_QUEUE + 3  # each answered exactly once
    assert not b.pipe.busy


def test_a_load_that_fails_to_prepare_or_install_is_answered_with_why() -> None:
    b = Bench(failing={"nope"}, refused={"later"})
    b.ask("nope")
    b.tick()
    b.finish("nope")
    b.ask("later")
    b.tick()
    b.finish("later")
    b.settle()
    assert b.replies == [
        ("nope", {"ok": False, "command": "load_scene", "error": "no scene 'nope'"}),
        ("later", {"ok": False, "command": "load_scene", "error": "the robot is calibrating"}),
    ]
    assert b.installed == [] and b.disposed == []


def test_shutdown_answers_what_waits() -> None:
    b = Bench()
    b.ask("x")
    b.ask("y")
    b.tick()
    b.release.setdefault("x", threading.Event()).set()
    b.pipe.shutdown()
    assert [(n, r["error"]) for n, r in b.replies] == [
        ("y", "the daemon is shutting down"),
        ("x", "the daemon is shutting down"),
    ]
    assert b.installed == []

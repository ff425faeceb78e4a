"""Issue 7 §1: fuzzed wire messages through the daemon's real message path.

Joystick, command and object-pose payloads of four kinds — structured-but-wrong JSON
objects (right keys, wrong types, NaN, infinities, huge, negative, nested, extra keys,
another schema), mutated valid payloads (byte flips, truncation, duplication), arbitrary
bytes, and valid messages — go through the calls the service makes on receipt
(:meth:`JoystickInbox.offer`, :func:`parse` + the controller's verbs, :func:`parse` +
:meth:`Controller.observe`) and the loop's :meth:`Controller.tick` on the real stand-in.

After every payload: nothing escapes but the project's own errors (from ``tick`` and
``observe``, which the loop calls unguarded: nothing at all); every rejection is counted;
a rejected payload leaves what the next tick commands unchanged; and after every tick
what was sent is finite and at most ``v_max``, the EE is inside the workspace box, the
joints are within their limits, and no input means exactly zero velocity.

1,000 examples per message kind in the suite (``LEGWS_FUZZ_EXAMPLES`` sets another
number: docs/reliability.md's table is a run of 10,000); the terminal summary lists the
payloads, rejections and times.
"""

from __future__ import annotations

import json
import math
import os
from collections import Counter
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from legws_daemon.daemon.service import catalog_scene, catalog_taskgraph
from legws_daemon.errors import InputError, LegwsError
from legws_daemon.formats.messages import MAX_PAYLOAD, CommandRequest, ObjectsMessage, parse
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import ObjectPose, Scene
from legws_daemon.task.graph import TaskGraph
from tests.autonomy.rig import operator_command
from tests.reliability.helpers import TALLIES, Rig, Tally, expect
from tests.reliability.strategies import EDGE_TEXT, junk, leaves, mutated, nested

EXAMPLES = int(os.environ.get("LEGWS_FUZZ_EXAMPLES", "1000"))
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    suppress_health_check=[
        HealthCheck.function_scoped_fixture,  # one rig per test, shared by its examples
        HealthCheck.too_slow,
        HealthCheck.data_too_large,
        HealthCheck.large_base_example,
    ],
)


def encode(doc: Any) -> bytes:
    """JSON as a publisher might write it (NaN and Infinity as Python's json writes them)."""
    return json.dumps(doc, allow_nan=True).encode()


#: Payloads no publisher would send, by recipe (large ones built when drawn).
ODD_PAYLOADS: dict[str, Callable[[], bytes]] = {
    "empty": lambda: b"",
    "bom": lambda: b"\xef\xbb\xbf{}",
    "over 64 KiB of braces": lambda: b"{" * (MAX_PAYLOAD + 1),
    "over 64 KiB of spaces": lambda: b" " * (MAX_PAYLOAD + 1),
    "50,000 open brackets": lambda: b"[" * 50_000,
    "5,000 nested lists": lambda: b"[" * 5_000 + b"]" * 5_000,
    "a 5,000-digit number": lambda: b"1" * 5_000,
    "a 5,000-digit seq": lambda: b'{"schema": 1, "seq": ' + b"9" * 5_000 + b"}",
    "null": lambda: b"null",
    "empty list": lambda: b"[]",
    "a string": lambda: b'"schema"',
    "NaN": lambda: b"NaN",
}
arbitrary_bytes = st.one_of(
    st.binary(max_size=400),
    st.text(max_size=200).map(str.encode),
    st.sampled_from(sorted(ODD_PAYLOADS)).map(lambda name: ODD_PAYLOADS[name]()),
)


# --- joystick --------------------------------------------------------------------------
#: Placeholder for "the rig's next seq" (a valid message must be newer than the last).
NEXT = "<next seq>"

unit = st.floats(-1.0, 1.0)
axes = st.one_of(
    st.tuples(unit, unit, unit).map(
        lambda a: tuple(x / max(1.0, math.sqrt(sum(c * c for c in a))) for x in a)
    ),
    st.sampled_from(
        [
            (0.0, 0.0, 0.0),
            (1.0, 0.0, 0.0),
            (0.0, -1.0, 0.0),
            (0.0, 0.0, -1.0),
            (0.6, 0.0, -0.8),
            (-0.0, 0.0, 0.0),
            (0.57735, 0.57735, 0.57735),
        ]
    ),
)
rare = st.sampled_from([False] * 19 + [True])  # buttons: a confirm commits, a cancel cancels
buttons = st.fixed_dictionaries({}, optional={"cancel": rare, "confirm": rare})
valid_joystick = st.fixed_dictionaries(
    {
        "schema": st.just(1),
        "seq": st.just(NEXT),
        "stamp": st.floats(-1e12, 1e12),
        "axes": axes.map(list),
        "buttons": buttons,
    },
    optional={"source": st.sampled_from(["rig", "sim-user", "x" * 64])},
)
JOYSTICK_FIELDS = ["schema", "seq", "stamp", "axes", "buttons", "source"]
#: What a broken joystick message can get wrong (see ``wrong_joystick``).
JOYSTICK_OPS = ["junk", "axis", "length", "norm", "button", "delete", "extra", "schema", "nest",
                "top"]  # fmt: skip


@st.composite
def wrong_joystick(draw: st.DrawFn) -> Any:
    """A joystick object with 1-3 fields broken (it may, rarely, still be valid)."""
    doc: Any = draw(valid_joystick)
    doc["seq"] = draw(st.integers(0, 2**40))
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(JOYSTICK_OPS))
        if not isinstance(doc, dict):
            break
        key = draw(st.sampled_from(JOYSTICK_FIELDS))
        if op == "junk":
            doc[key] = draw(junk)
        elif op == "axis":
            i = draw(st.integers(0, 2))
            doc["axes"] = [*draw(axes)]
            doc["axes"][i] = draw(leaves)
        elif op == "length":
            doc["axes"] = draw(st.lists(unit, max_size=6).filter(lambda a: len(a) != 3))
        elif op == "norm":  # each axis in range, the deflection too long
            a = np.array(draw(st.tuples(unit, unit, unit))) + 1e-3
            scale = draw(st.floats(1.0 + 1e-5, 1.8)) / float(np.linalg.norm(a))
            doc["axes"] = list(np.clip(a * scale, -1.0, 1.0))
        elif op == "button":
            doc["buttons"] = {draw(st.sampled_from(["cancel", "confirm", "fire"])): draw(leaves)}
        elif op == "delete":
            doc.pop(key, None)
        elif op == "extra":
            doc[
                draw(st.text(min_size=1, max_size=8).filter(lambda k: k not in JOYSTICK_FIELDS))
            ] = draw(junk)
        elif op == "schema":
            doc["schema"] = draw(st.sampled_from([0, 2, -1, "1", None, 1.5, [1], {"v": 1}]))
        elif op == "nest":
            doc[key] = nested(doc.get(key), draw(st.integers(1, 60)))
        else:
            doc = draw(st.sampled_from([[doc], {"message": doc}, "joystick", 1, None]))
    return doc


def valid_bytes(docs: st.SearchStrategy[dict[str, Any]]) -> st.SearchStrategy[bytes]:
    """Encoded valid documents with a fixed seq (for byte mutations)."""

    def fix(doc: dict[str, Any], seq: int) -> bytes:
        return encode({**doc, "seq": seq} if "seq" in doc else doc)

    return st.builds(fix, docs, st.integers(0, 2**63 - 1))


def payloads(
    valid: st.SearchStrategy[dict[str, Any]], wrong: st.SearchStrategy[Any]
) -> st.SearchStrategy[tuple[str, Any]]:
    """``(kind, payload)``: a document (encoded when fed) or raw bytes."""
    return st.one_of(
        st.tuples(st.just("structured"), wrong),
        st.tuples(st.just("mutated"), mutated(valid_bytes(valid))),
        st.tuples(st.just("bytes"), arbitrary_bytes),
        st.tuples(st.just("valid"), valid),
    )


def fill_seq(rig: Rig, doc: Any) -> bytes:
    if isinstance(doc, bytes):
        return doc
    if isinstance(doc, dict) and doc.get("seq") == NEXT:
        doc = {**doc, "seq": rig.next_seq()}
    return encode(doc)


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = Rig()
    yield r
    r.c.shutdown()


def tally_for(name: str) -> Tally:
    return TALLIES.setdefault(name, Tally())


@pytest.mark.slow
@FUZZ
@given(
    item=payloads(valid_joystick, wrong_joystick()),
    gap=st.sampled_from([1, 1, 1, 1, 1, 2, 3, 7]),  # 7 ticks: past the deadman timeout
)
def test_joystick_payloads_never_crash_and_never_leave_the_envelope(
    rig: Rig, item: tuple[str, Any], gap: int
) -> None:
    tally = tally_for("joystick")
    kind, doc = item
    payload = fill_seq(rig, doc)
    box = rig.inbox
    before, ignored_before = Counter(box.counts()), box.ignored
    rejected_before = box.rejected
    sample = rig.offer(payload)
    moved = Counter(box.counts()) - before
    if kind == "valid":  # never invalid: taken, or not input (stale, another's, nobody's)
        assert not moved["invalid"], payload
    ignored = box.ignored > ignored_before
    outcome = "accepted" if sample is not None else "ignored" if ignored else ""
    outcome = outcome or next(iter(moved), "accepted")  # a goodbye is taken, not used
    if box.rejected > rejected_before:
        assert box.last_error is not None
        assert "\n" not in box.last_error
    tally.examples += 1
    tally.payloads += 1
    tally.outcomes[f"{kind} {outcome}"] += 1
    for _ in range(gap):
        rig.tick()
    rig.restart_if_done()
    tally.ticks = rig.ticks
    tally.modes = rig.modes
    tally.reasons = Counter(box.invalid_fields)


# --- commands ----------------------------------------------------------------------------
SCENE_ARGUMENTS = ["desk", "tea", "nope", "../desk", "desk.toml", ".desk", "Desk", "desk/"]
GRAPH_ARGUMENTS = ["tea", "feeding", "nope", "../tea", "tea.toml", "Tea", "tea feeding"]
SIMPLE_COMMANDS = ["status", "reset", "stop"]
COMMAND_MIX = ["simple"] * 8 + ["load_scene", "load_taskgraph"]  # loads: a fifth of valid ones


def command_doc(which: str) -> st.SearchStrategy[dict[str, Any]]:
    if which == "simple":
        return st.fixed_dictionaries(
            {"schema": st.just(1), "command": st.sampled_from(SIMPLE_COMMANDS)}
        )
    names = SCENE_ARGUMENTS if which == "load_scene" else GRAPH_ARGUMENTS
    return st.fixed_dictionaries(
        {"schema": st.just(1), "command": st.just(which), "argument": st.sampled_from(names)}
    )


valid_command = st.sampled_from(COMMAND_MIX).flatmap(command_doc)
COMMAND_FIELDS = ["schema", "command", "argument"]


@st.composite
def wrong_command(draw: st.DrawFn) -> Any:
    doc: Any = draw(valid_command)
    for _ in range(draw(st.integers(1, 3))):
        if not isinstance(doc, dict):
            break
        op = draw(st.sampled_from(["junk", "delete", "extra", "argument", "name", "nest", "top"]))
        key = draw(st.sampled_from(COMMAND_FIELDS))
        if op == "junk":
            doc[key] = draw(junk)
        elif op == "delete":
            doc.pop(key, None)
        elif op == "extra":
            doc[draw(st.sampled_from(["args", "Command", "", "x" * 100]))] = draw(junk)
        elif op == "argument":
            doc["argument"] = draw(st.sampled_from(EDGE_TEXT) | leaves)
        elif op == "name":
            doc["command"] = draw(
                st.sampled_from(["STOP", "halt", "shutdown", "load", "reset ", "", "exec"])
            )
        elif op == "nest":
            doc[key] = nested(doc.get(key), draw(st.integers(1, 60)))
        else:
            doc = draw(st.sampled_from([[doc], {"request": doc}, "stop", None]))
    return doc


def snapshot(rig: Rig) -> tuple[Any, ...]:
    """What a command could change: mode, stage, commitment, adapter, arm, layout."""
    c = rig.c
    return (c.mode, c.stage, c.committed, c.adapter, c.assistant, dict(c.layout),
            c.adapter.read_state().q.tobytes())  # fmt: skip


@pytest.fixture(scope="module")
def loaders() -> tuple[Callable[[str], Scene], Callable[[str], tuple[TaskGraph, Scene]]]:
    """The service's catalog loaders, with each scene parsed once (same object: same world)."""
    scenes: dict[str, Scene] = {}

    def scene(name: str) -> Scene:
        fresh = catalog_scene(name)  # the real checks first
        return scenes.setdefault(fresh.name, fresh)

    def graph(name: str) -> tuple[TaskGraph, Scene]:
        g, fresh = catalog_taskgraph(name)
        return g, scenes.setdefault(fresh.name, fresh)

    scenes["desk"] = load_scene("desk")
    return scene, graph


@pytest.mark.slow
@FUZZ
@given(
    item=payloads(valid_command, wrong_command()),
    sticks=st.lists(st.one_of(st.none(), axes), min_size=1, max_size=3),
)
def test_command_payloads_never_crash_and_never_leave_the_envelope(
    rig: Rig,
    loaders: tuple[Callable[[str], Scene], Callable[[str], tuple[TaskGraph, Scene]]],
    item: tuple[str, Any],
    sticks: list[tuple[float, float, float] | None],
) -> None:
    tally = tally_for("command")
    kind, doc = item
    payload = doc if isinstance(doc, bytes) else encode(doc)
    before = snapshot(rig)
    tally.examples += 1
    tally.payloads += 1
    request, error = expect(InputError, parse, CommandRequest, payload, "legws/sawyer_sim/command")
    if isinstance(error, InputError):  # the reply is an error payload; nothing else happens
        tally.outcomes[f"{kind} rejected"] += 1
        tally.reasons[error.field or "payload"] += 1
        assert snapshot(rig) == before
    if request is not None:
        # refused (an unknown name, a path, the robot failing): an error reply
        _, refused = expect(LegwsError, operator_command, rig.c, request, None, loaders)
        tally.outcomes[f"{kind} {'refused' if refused else 'done'}"] += 1
        if request.command == "stop":
            assert rig.c.mode == "stopped"
        if request.command == "reset":
            assert rig.c.mode == "assist"
    for stick in sticks:
        if stick is not None:
            rig.offer(rig.joystick(stick))
        record = rig.tick()
        if rig.c.mode == "stopped":
            np.testing.assert_array_equal(record.command, np.zeros(3))
    rig.restart_if_done()
    tally.ticks = rig.ticks
    tally.modes = rig.modes


# --- object poses ------------------------------------------------------------------------
DESK = load_scene("desk")
OBJECT_NAMES = [*DESK.objects, "mouth", "unknown_thing", "White_Mug", "x" * 64]
coordinate = st.one_of(
    st.floats(-100.0, 100.0), st.floats(0.2, 0.9), st.sampled_from([-100.0, 100.0, 0.0, -0.0])
)
pose = st.fixed_dictionaries(
    {"x": coordinate, "y": coordinate}, optional={"yaw": st.floats(-100.0, 100.0)}
)
valid_objects = st.fixed_dictionaries(
    {
        "schema": st.just(1),
        "seq": st.integers(0, 2**63 - 1),
        "stamp": st.floats(-1e12, 1e12),
        "objects": st.dictionaries(
            st.sampled_from(OBJECT_NAMES) | st.text(min_size=1, max_size=64), pose, max_size=6
        ),
    },
    optional={"source": st.sampled_from(["tracker", "tape measure"])},
)
OBJECT_FIELDS = ["schema", "seq", "stamp", "objects", "source"]


@st.composite
def wrong_objects(draw: st.DrawFn) -> Any:
    doc: Any = draw(valid_objects)
    for _ in range(draw(st.integers(1, 3))):
        if not isinstance(doc, dict):
            break
        op = draw(st.sampled_from(["junk", "pose", "field", "many", "name", "delete", "extra",
                                   "nest", "top"]))  # fmt: skip
        key = draw(st.sampled_from(OBJECT_FIELDS))
        current = doc.get("objects")
        objects: dict[str, Any] = current if isinstance(current, dict) else {}
        if op == "junk":
            doc[key] = draw(junk)
        elif op == "pose":
            objects[draw(st.sampled_from(OBJECT_NAMES))] = draw(junk)
            doc["objects"] = objects
        elif op == "field":
            name = draw(st.sampled_from(list(DESK.movable)))
            p = dict(draw(pose))
            p[draw(st.sampled_from(["x", "y", "yaw", "z"]))] = draw(leaves)
            objects[name] = p
            doc["objects"] = objects
        elif op == "many":
            doc["objects"] = {
                f"o{i}": {"x": 0.5, "y": 0.0} for i in range(draw(st.integers(65, 80)))
            }
        elif op == "name":
            objects[draw(st.sampled_from(["", "x" * 65]))] = {"x": 0.5, "y": 0.0}
            doc["objects"] = objects
        elif op == "delete":
            doc.pop(key, None)
        elif op == "extra":
            doc[draw(st.sampled_from(["poses", "Objects", "z", ""]))] = draw(junk)
        elif op == "nest":
            doc[key] = nested(doc.get(key), draw(st.integers(1, 60)))
        else:
            doc = draw(st.sampled_from([[doc], {"objects": doc}, "objects", 0]))
    return doc


@pytest.mark.slow
@FUZZ
@given(
    item=payloads(valid_objects, wrong_objects()),
    sticks=st.lists(st.one_of(st.none(), axes), min_size=1, max_size=2),
    confirm=rare,
)
def test_object_payloads_never_crash_and_never_leave_the_envelope(
    rig: Rig, item: tuple[str, Any], sticks: list[tuple[float, float, float] | None], confirm: bool
) -> None:
    tally = tally_for("objects")
    kind, doc = item
    payload = doc if isinstance(doc, bytes) else encode(doc)
    c = rig.c

    def layouts() -> tuple[object, ...]:
        return (dict(c.layout), dict(c.layouts.observed), c.stage.certificate, len(rig.events))

    before = layouts()
    tally.examples += 1
    tally.payloads += 1
    msg, error = expect(InputError, parse, ObjectsMessage, payload, "legws/sawyer_sim/objects")
    if isinstance(error, InputError):  # counted (status objects_rejected) and dropped
        tally.outcomes[f"{kind} rejected"] += 1
        tally.reasons[error.field or "payload"] += 1
        assert layouts() == before
    if msg is not None:
        tally.outcomes[f"{kind} accepted"] += 1
        for p in msg.objects.values():
            assert all(math.isfinite(v) and abs(v) <= 100.0 for v in (p.x, p.y, p.yaw))
        # the loop applies them unguarded: observe may raise nothing at all
        c.observe({n: ObjectPose(p.x, p.y, p.yaw) for n, p in msg.objects.items()})
        for n, p in msg.objects.items():
            if n in c.scene.movable:
                assert c.layout[n] == ObjectPose(p.x, p.y, p.yaw)
    for stick in sticks:
        if stick is not None:
            # a confirm commits: assistance then heads for the reported (maybe far) poses
            rig.offer(rig.joystick(stick, confirm=confirm))
        rig.tick()
    rig.restart_if_done()
    tally.ticks = rig.ticks
    tally.modes = rig.modes

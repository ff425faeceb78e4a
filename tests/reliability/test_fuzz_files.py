"""Issue 7 §1: fuzzed files through every loader — each failure is one clear line.

Scene files, hardware profiles, task graphs (TOML) and goal sets, layouts and plans (JSON)
are generated from the shipped, valid documents: fields replaced by wrong types, NaN,
infinities, huge or negative numbers, unicode, deep nesting, extra or missing keys; the
written text mutated (byte flips, truncation, duplication); a UTF-8 BOM; random text and
binary. Each goes through the real loader from a file. A document may happen to be valid;
otherwise the only error is the project's :class:`LegwsError` (an :class:`InputError`)
whose message is one line naming the file — never a traceback. A handful of broken files
per kind also go through the ``legws`` command line: exit 2 and one ``legws: error:`` line.

800 examples per loader in the suite (docs/reliability.md: runs of 1,500 and 6,000).
"""

from __future__ import annotations

import copy
import json
import os
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from legws_daemon.cli.main import run
from legws_daemon.errors import LegwsError
from legws_daemon.formats.goalset import load_goalset
from legws_daemon.formats.profile import load_profile, profiles_dir
from legws_daemon.scene.catalog import load_scene, scenes_dir
from legws_daemon.scene.layout_file import layout_to_data, load_layout
from legws_daemon.scene.scene import Scene
from legws_daemon.task.plan_file import load_plan, plan_to_data
from legws_daemon.task.taskgraph_file import load_taskgraph, taskgraphs_dir
from tests.cli.helpers import EXAMPLE_GOALSET, Result, assert_bad_input_lines
from tests.formats.helpers import toml_dumps
from tests.reliability.helpers import TALLIES, Tally, expect
from tests.reliability.strategies import EDGE_TEXT, junk, leaves, mutated, nested
from tests.task.test_plan_file import feeding_plan

#: Examples per loader in the suite (``LEGWS_FUZZ_FILE_EXAMPLES`` sets another number:
#: docs/reliability.md's table is a run of 1,500).
EXAMPLES = int(os.environ.get("LEGWS_FUZZ_FILE_EXAMPLES", "500"))
FILES = settings(
    max_examples=EXAMPLES,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


def json_text(doc: Any) -> str:
    return json.dumps(doc, allow_nan=True, indent=1)


# --- mutations of documents -------------------------------------------------------------
def paths(doc: Any, here: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every place in a document: the root, each key of a table, each item of a list."""
    out = [here]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += paths(v, (*here, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += paths(v, (*here, i))
    return out


def _parent(doc: Any, path: tuple[Any, ...]) -> Any:
    for key in path[:-1]:
        doc = doc[key]
    return doc


#: Names a file may hold by mistake: line breaks of every kind, and the edge cases.
BROKEN_NAMES = ["white_mug\n", "a\nb", "\r", "x\u2028y", "tab\there", "\x85", *EDGE_TEXT]


@st.composite
def mutated_document(draw: st.DrawFn, base: Any) -> Any:
    """``base`` with 1-4 changes at random places."""
    doc = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 4))):
        path = draw(st.sampled_from(paths(doc)))
        op = draw(
            st.sampled_from(["junk", "leaf", "delete", "extra", "nest", "copy", "huge", "rename"])
        )
        if not path:  # the root
            if op in ("junk", "leaf"):
                return draw(junk)
            if op == "nest":
                return nested(doc, draw(st.integers(1, 40)))
            if isinstance(doc, dict):
                doc[draw(st.text(min_size=1, max_size=10))] = draw(junk)
            continue
        parent, key = _parent(doc, path), path[-1]
        if op == "junk":
            parent[key] = draw(junk)
        elif op == "leaf":
            parent[key] = draw(leaves)
        elif op == "huge":
            parent[key] = draw(st.sampled_from([1e308, -1e308, 10**300, -(2**70), 1e-320]))
        elif op == "delete":
            del parent[key]
        elif op == "extra" and isinstance(parent[key], dict):
            parent[key][draw(st.text(min_size=1, max_size=10))] = draw(junk)
        elif op == "extra" and isinstance(parent[key], list):
            parent[key].append(draw(junk))
        elif op == "nest":
            parent[key] = nested(parent[key], draw(st.integers(1, 40)))
        elif op == "copy" and isinstance(parent, list):
            parent.append(copy.deepcopy(parent[key]))  # e.g. a repeated object or stage
        elif op == "rename" and isinstance(parent, dict):  # e.g. an object name with a "\n"
            parent[draw(st.sampled_from(BROKEN_NAMES) | st.text(max_size=8))] = parent.pop(key)
    return doc


#: Whole-file contents no editor would write.
ODD_TEXT: dict[str, Callable[[str], bytes]] = {
    "bom": lambda ext: b"\xef\xbb\xbf" + (b"{}" if ext == "json" else b"a = 1"),
    "binary": lambda ext: bytes(range(256)) * 4,
    "latin-1": lambda ext: "name = 'caf\u00e9'".encode("latin-1"),
    "deep lists": lambda ext: (b"a = " if ext == "toml" else b"") + b"[" * 5_000 + b"]" * 5_000,
    "deep tables": lambda ext: (
        b"a = " + b"{b = " * 3_000 + b"1" + b"}" * 3_000
        if ext == "toml"
        else b'{"a": ' * 3_000 + b"1" + b"}" * 3_000
    ),
    "5,000-digit number": lambda ext: (b"a = " if ext == "toml" else b"") + b"7" * 5_000,
    "empty": lambda ext: b"",
    "nul bytes": lambda ext: b"\x00" * 64,
    "lone surrogate": lambda ext: '"\ud800"'.encode("utf-8", "surrogatepass"),
}


def file_contents(base: Any, ext: str) -> st.SearchStrategy[bytes]:
    """Contents of a file of kind ``ext`` derived from the valid document ``base``."""
    write = toml_dumps if ext == "toml" else json_text

    def encode(doc: Any) -> bytes:
        return write(doc).encode("utf-8", "surrogatepass")

    documents = mutated_document(base).map(encode)
    return st.one_of(
        documents,
        documents,  # structured mutations twice as often as the rest
        mutated(st.just(encode(base))),
        st.sampled_from(sorted(ODD_TEXT)).map(lambda name: ODD_TEXT[name](ext)),
        st.binary(max_size=300),
        st.text(max_size=300).map(lambda t: t.encode("utf-8", "surrogatepass")),
    )


def check_load(name: str, path: Path, contents: bytes, load: Callable[[Path], object]) -> None:
    """Write ``contents`` to ``path`` and load it: success, or one line naming the file."""
    tally = TALLIES.setdefault(f"file {name}", Tally())
    tally.examples += 1
    tally.payloads += 1
    path.write_bytes(contents)
    _, error = expect(LegwsError, load, path)  # (one line: checked there)
    if error is not None:
        message = str(error)
        assert "\n" not in message and "\r" not in message, message
        assert str(path) in message, message
        tally.outcomes["error"] += 1
        return
    tally.outcomes["valid"] += 1


# --- the valid documents ------------------------------------------------------------------
def toml_doc(path: Path) -> dict[str, Any]:
    return tomllib.loads(path.read_text(encoding="utf-8"))


DESK_SCENE = toml_doc(scenes_dir() / "desk.toml")
SIM_PROFILE = toml_doc(profiles_dir() / "sim.toml")
TEA_GRAPH = toml_doc(taskgraphs_dir() / "tea.toml")
DESK = load_scene("desk")
FEEDING = load_scene("feeding")
DESK_LAYOUT = layout_to_data(DESK.default_layout())
FEEDING_PLAN = plan_to_data(feeding_plan())


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz_files")


def _scene(path: Path) -> Scene:
    return load_scene(path)


@pytest.mark.slow
@FILES
@given(contents=file_contents(DESK_SCENE, "toml"))
def test_scene_files(folder: Path, contents: bytes) -> None:
    check_load("scene", folder / "desk.toml", contents, _scene)


@pytest.mark.slow
@FILES
@given(contents=file_contents(SIM_PROFILE, "toml"))
def test_hardware_profiles(folder: Path, contents: bytes) -> None:
    check_load("profile", folder / "sim.toml", contents, load_profile)


@pytest.mark.slow
@FILES
@given(contents=file_contents(TEA_GRAPH, "toml"))
def test_task_graphs(folder: Path, contents: bytes) -> None:
    check_load("task graph", folder / "tea.toml", contents, load_taskgraph)


@pytest.mark.slow
@FILES
@given(contents=file_contents(EXAMPLE_GOALSET, "json"))
def test_goal_sets(folder: Path, contents: bytes) -> None:
    check_load("goal set", folder / "goals.json", contents, load_goalset)


@pytest.mark.slow
@FILES
@given(contents=file_contents(DESK_LAYOUT, "json"))
def test_layouts(folder: Path, contents: bytes) -> None:
    check_load("layout", folder / "layout.json", contents, lambda p: load_layout(p, DESK))


@pytest.mark.slow
@FILES
@given(contents=file_contents(FEEDING_PLAN, "json"))
def test_plans(folder: Path, contents: bytes) -> None:
    check_load("plan", folder / "plan.json", contents, lambda p: load_plan(p, FEEDING))


# --- names with line breaks ---------------------------------------------------------------
def _goal_set(first: str, second: str, at_x0: bool = False) -> dict[str, Any]:
    doc = copy.deepcopy(EXAMPLE_GOALSET)
    doc["goals"][0]["name"], doc["goals"][1]["name"] = first, second
    if at_x0:
        doc["goals"][0]["position"] = doc["x0"]["position"]
    return doc


#: A name or key with a line break where each loader quotes it in a message.
LINE_BREAKS: dict[str, tuple[str, bytes, Callable[[Path], object]]] = {
    "layout object": ("layout.json", json.dumps({"a\nb": {"x": 0.5, "y": 0.0}}).encode(),
                      lambda p: load_layout(p, DESK)),
    "repeated goal": ("goals.json", json.dumps(_goal_set("a\nb", "a\nb")).encode(),
                      load_goalset),
    "goal at x0": ("goals.json", json.dumps(_goal_set("a\u2028b", "c", at_x0=True)).encode(),
                   load_goalset),
    "profile key": ("sim.toml", toml_dumps({**SIM_PROFILE, "\r": 1}).encode(), load_profile),
    "scene object": ("desk.toml", toml_dumps(
        {**DESK_SCENE, "objects": [{**DESK_SCENE["objects"][0], "name": "mug\n"},
                                   *DESK_SCENE["objects"][1:]]}).encode(), _scene),
    "stage name": ("tea.toml", toml_dumps(
        {**TEA_GRAPH, "stages": [{**TEA_GRAPH["stages"][0], "next": ["steep\x85"]},
                                 *TEA_GRAPH["stages"][1:]]}).encode(), load_taskgraph),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(LINE_BREAKS))
def test_names_with_line_breaks_stay_on_one_line(folder: Path, case: str) -> None:
    name, contents, load = LINE_BREAKS[case]
    path = folder / name
    path.write_bytes(contents)
    _, error = expect(LegwsError, load, path)
    assert error is not None
    assert str(path) in str(error)


# --- the command line -----------------------------------------------------------------
#: A few broken files per kind: (file name, contents).
BROKEN: dict[str, list[bytes]] = {
    "toml": [
        ODD_TEXT["deep lists"]("toml"),
        ODD_TEXT["5,000-digit number"]("toml"),
        ODD_TEXT["bom"]("toml"),
        ODD_TEXT["binary"]("toml"),
        b"schema_version = 1\nname = nan\n",
    ],
    "json": [
        ODD_TEXT["deep lists"]("json"),
        ODD_TEXT["5,000-digit number"]("json"),
        ODD_TEXT["bom"]("json"),
        ODD_TEXT["binary"]("json"),
        b'{"x0": NaN}',
    ],
}
#: How the command line reads each kind of file (``{}``: the file).
COMMANDS: dict[str, tuple[str, list[str]]] = {
    "scene": ("desk.toml", ["certify", "--scene", "{}"]),
    "profile": ("sim.toml", ["daemon", "--profile", "{}", "--duration", "0.1"]),
    "task graph": ("tea.toml", ["taskgraph", "check", "{}"]),
    "goal set": ("goals.json", ["certify", "{}"]),
    "layout": ("layout.json", ["certify", "--scene", "desk", "--layout", "{}"]),
    "plan": (
        "plan.json",
        ["daemon", "--taskgraph", "feeding", "--plan", "{}", "--duration", "0.1"],
    ),
}


@pytest.mark.parametrize("kind", sorted(COMMANDS))
def test_the_command_line_says_one_line_and_exits_2(
    kind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    name, argv = COMMANDS[kind]
    path = tmp_path / name
    for contents in BROKEN[name.rsplit(".", 1)[1]]:
        path.write_bytes(contents)
        capsys.readouterr()
        code = run([str(path) if a == "{}" else a for a in argv])
        captured = capsys.readouterr()
        # a line per error (a JSON NaN where a table goes: that, and what is missing)
        assert_bad_input_lines(Result(code, captured.out, captured.err), name)

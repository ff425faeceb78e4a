"""Task-graph checks stay linear in stages and transitions: no path is listed.

A layered graph of k two-way choices has 2^k paths; the 64-stage limit allows k = 31
(2^31 paths), and a chain of optional dips of 64 stages has about 10^13. `legws taskgraph
check|show` and the daemon's load must handle both. The held-object check and the path
count are compared with a brute-force walk of every path on small random graphs.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from legws_daemon.cli.main import run
from legws_daemon.errors import InputError
from legws_daemon.scene.catalog import load_scene
from legws_daemon.task import diagram
from legws_daemon.task.actions import action
from legws_daemon.task.graph import ACTIONS, Stage, TaskGraph, topological_order
from legws_daemon.task.taskgraph_file import HeldProblem, held_problem, load_taskgraph

MAX_STAGES = 64
#: Layers of a layered graph at the stage limit: a start, 2 stages a layer, an end.
MAX_LAYERS = (MAX_STAGES - 2) // 2


def _stage(name: str, candidates: list[str], act: str, nxt: list[str]) -> str:
    quoted = ", ".join(f'"{c}"' for c in candidates)
    text = f'[[stages]]\nname = "{name}"\ncandidates = [{quoted}]\naction = "{act}"\n'
    if nxt:
        text += "next = [" + ", ".join(f'"{n}"' for n in nxt) + "]\n"
    return text + "\n"


def _header(name: str, repeat: bool) -> str:
    text = f'schema_version = 1\nname = "{name}"\nscene = "feeding"\n'
    if repeat:
        text += 'repeat = "until_consumed"\n'
    return text + "\n"


def layered_toml(
    layers: int,
    name: str = "layered",
    *,
    repeat: bool = False,
    actions: dict[str, str] | None = None,
) -> str:
    """A feeding graph: pick a food, then ``layers`` two-way choices (dip in chocolate,
    ``a<i>``, or in sprinkles, ``b<i>``; both lead to both stages of the next layer), then
    feed. 2 * layers + 2 stages, 2^layers paths. ``actions`` replaces stages' actions."""
    actions = actions or {}

    def layer(i: int) -> list[str]:
        return [f"a{i}", f"b{i}"] if i <= layers else ["feed"]

    text = _header(name, repeat)
    text += _stage(
        "food", ["strawberry", "grape", "brownie"], actions.get("food", "pick"), layer(1)
    )
    for i in range(1, layers + 1):
        for stage, bowl in zip(layer(i), ["chocolate_bowl", "sprinkles_bowl"], strict=True):
            text += _stage(stage, [bowl], actions.get(stage, "dip"), layer(i + 1))
    return text + _stage("feed", ["mouth"], actions.get("feed", "feed"), [])


def chain_toml(dips: int, name: str = "chain", *, actions: dict[str, str] | None = None) -> str:
    """A feeding graph: pick a food, ``dips`` dips ``d1``... each of which may be skipped
    (every stage but the last two is a two-way choice: the next stage or the one after),
    then feed. dips + 2 stages, Fibonacci(dips + 2) paths."""
    actions = actions or {}
    names = ["food", *(f"d{i}" for i in range(1, dips + 1)), "feed"]
    candidates = [["strawberry", "grape", "brownie"]]
    candidates += [["chocolate_bowl" if i % 2 else "sprinkles_bowl"] for i in range(1, dips + 1)]
    candidates += [["mouth"]]
    default = ["pick", *(["dip"] * dips), "feed"]
    text = _header(name, False)
    for i, stage in enumerate(names):
        text += _stage(stage, candidates[i], actions.get(stage, default[i]), names[i + 1 : i + 3])
    return text


def write(folder: Path, name: str, text: str) -> Path:
    path = folder / f"{name}.toml"
    path.write_text(text, encoding="utf-8")
    return path


def fibonacci(n: int) -> int:
    a, b = 0, 1
    for _ in range(n):
        a, b = b, a + b
    return a


def cli(capsys: pytest.CaptureFixture[str], *argv: str | Path) -> tuple[int, str, str]:
    capsys.readouterr()
    code = run([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def assert_is_path(graph: TaskGraph, names: list[str]) -> None:
    """``names`` starts at the start and follows transitions of the graph."""
    assert names[0] == graph.start
    for a, b in itertools.pairwise(names):
        assert b in graph.stages[a].next, f"{a} -> {b} is no transition"


# --- the largest graphs the format allows --------------------------------------------------


def test_a_64_stage_layered_graph_is_accepted(tmp_path: Path) -> None:
    graph, _ = load_taskgraph(write(tmp_path, "layered", layered_toml(MAX_LAYERS)))
    assert len(graph.stages) == MAX_STAGES
    assert graph.path_count() == 2**MAX_LAYERS
    order = graph.order()
    assert sorted(order) == sorted(graph.stages)
    position = {n: i for i, n in enumerate(order)}
    assert all(position[s.name] < position[n] for s in graph.stages.values() for n in s.next)


def test_one_more_layer_is_over_the_stage_limit(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="at most 64"):
        load_taskgraph(write(tmp_path, "layered", layered_toml(MAX_LAYERS + 1)))


def test_a_64_stage_chain_of_optional_steps_is_accepted(tmp_path: Path) -> None:
    graph, _ = load_taskgraph(write(tmp_path, "chain", chain_toml(MAX_STAGES - 2)))
    assert len(graph.stages) == MAX_STAGES
    assert sum(len(s.next) > 1 for s in graph.stages.values()) == MAX_STAGES - 2
    assert graph.path_count() == fibonacci(MAX_STAGES) == 10610209857723


@pytest.mark.parametrize("layers", [1, 2, 3, 5, 8, 12])
def test_layered_path_count_is_two_to_the_layers(tmp_path: Path, layers: int) -> None:
    graph, _ = load_taskgraph(write(tmp_path, "layered", layered_toml(layers)))
    assert graph.path_count() == 2**layers == len(all_paths(graph))


def test_cli_check_of_64_stage_graphs(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    layered = write(tmp_path, "layered", layered_toml(MAX_LAYERS))
    code, out, err = cli(capsys, "taskgraph", "check", layered)
    assert (code, err) == (0, "")
    assert out == (
        f"{layered}: ok: 64 stages, 33 decision points (32 with inference, 31 choices), "
        "about 2.1e9 paths, scene feeding\n"
    )
    chain = write(tmp_path, "chain", chain_toml(MAX_STAGES - 2))
    code, out, err = cli(capsys, "taskgraph", "check", chain)
    assert (code, err) == (0, "")
    assert "64 stages" in out
    assert "about 1.1e13 paths" in out


def test_cli_show_prints_each_stage_once(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    graph_file = write(tmp_path, "layered", layered_toml(MAX_LAYERS))
    graph, _ = load_taskgraph(graph_file)
    code, out, err = cli(capsys, "taskgraph", "show", graph_file)
    assert (code, err) == (0, "")
    lines = out.splitlines()
    body = lines[lines.index("") + 1 :]
    for name, stage in graph.stages.items():  # expanded once, met again "shown above"
        expanded = [ln for ln in body if re.search(rf"(^|─ ){name}: {stage.action} ", ln)]
        assert len(expanded) == 1, name
    transitions = sum(len(s.next) for s in graph.stages.values())
    choices = sum(len(s.next) > 1 for s in graph.stages.values())
    assert len(body) == 1 + transitions + choices  # the start, a line per arrow and choice
    assert sum("(shown above)" in ln for ln in body) == transitions - (len(graph.stages) - 1)


@pytest.mark.parametrize("kind", ["layered", "chain"])
def test_show_png_of_64_stages_is_bounded(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, kind: str
) -> None:
    text = layered_toml(MAX_LAYERS) if kind == "layered" else chain_toml(MAX_STAGES - 2)
    graph_file = write(tmp_path, kind, text)
    png = tmp_path / f"{kind}.png"
    code, out, err = cli(capsys, "taskgraph", "show", graph_file, "--png", png)
    assert (code, err) == (0, "")
    assert out.rstrip().endswith(f"wrote {png}")
    with Image.open(png) as img:
        columns = MAX_LAYERS + 2 if kind == "layered" else MAX_STAGES
        assert (
            img.width
            == diagram.MARGIN
            + columns * diagram.BOX_WIDTH
            + (columns - 1) * (diagram.GAP_X)
            + diagram.MARGIN
        )
        assert img.width * img.height <= diagram.MAX_PIXELS
        if kind == "chain":  # 62 skips (d -> the one after next) share 3 lanes below the row
            assert img.height < 400


def test_a_diagram_over_the_pixel_limit_is_one_error_line(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(diagram, "MAX_PIXELS", 1_000_000)
    graph_file = write(tmp_path, "layered", layered_toml(MAX_LAYERS))
    png = tmp_path / "layered.png"
    code, out, err = cli(capsys, "taskgraph", "show", graph_file, "--png", png)
    assert (code, out) == (2, "")
    assert len(err.splitlines()) == 1
    assert re.match(
        rf"legws: error: {re.escape(str(graph_file))}: the diagram would be \d+x\d+ pixels, "
        "more than 1 million: too large to draw",
        err,
    )
    assert not png.exists()


@given(st.lists(st.tuples(st.integers(0, 50), st.integers(1, 30)), max_size=40))
def test_lanes_separate_overlapping_spans_and_use_no_more_than_needed(
    raw: list[tuple[int, int]],
) -> None:
    spans = [(float(a), float(a + w)) for a, w in raw]
    lane = diagram.lanes(spans, gap=2.0)
    for i, (a0, a1) in enumerate(spans):
        for j, (b0, b1) in enumerate(spans[:i]):
            if a0 <= b1 + 2.0 and b0 <= a1 + 2.0:  # closer than the gap
                assert lane[i] != lane[j]
    # as many lanes as spans closer than the gap over one point: no more are needed
    widest = max((sum(a <= x <= b + 2.0 for a, b in spans) for x, _ in spans), default=0)
    assert max(lane, default=-1) + 1 == widest


# --- a bad held state deep in a large graph: one line, one valid example path -------------


def test_pick_while_holding_deep_in_a_64_stage_graph(tmp_path: Path) -> None:
    text = layered_toml(MAX_LAYERS, actions={"b29": "pick"})
    graph_file = write(tmp_path, "layered", text)
    with pytest.raises(InputError) as info:
        load_taskgraph(graph_file)
    message = str(info.value)
    line = text.splitlines().index('name = "b29"') + 3  # the stage's action line
    prefix = f"{graph_file}:{line}: stages[58].action: 'pick' after "
    assert message.startswith(prefix)
    assert message.endswith(": the gripper already holds an object there")
    path = message[len(prefix) :].split(":")[0].split(" -> ")
    # the first path in the order of the next lists: every a up to the layer before
    assert path == ["food", *(f"a{i}" for i in range(1, 29))]
    graph, _ = load_taskgraph(write(tmp_path, "layered", layered_toml(MAX_LAYERS)))
    assert_is_path(graph, [*path, "b29"])


def test_place_then_dip_deep_in_a_64_stage_chain(tmp_path: Path) -> None:
    text = chain_toml(MAX_STAGES - 2, actions={"d40": "place"})
    with pytest.raises(InputError) as info:
        load_taskgraph(write(tmp_path, "chain", text))
    message = str(info.value)
    match = re.search(
        r"stages\[(\d+)\]\.action: '(\w+)' after (.*): the gripper holds nothing", message
    )
    assert match is not None, message
    # every path through d40 holds nothing at d41, or at d42 when d41 is skipped
    assert (match[1], match[2]) == ("41", "dip")
    assert match[3].split(" -> ") == ["food", *(f"d{i}" for i in range(1, 41))]


def test_repeated_graph_ending_with_a_held_object_names_a_path(tmp_path: Path) -> None:
    text = layered_toml(MAX_LAYERS, repeat=True, actions={"feed": "dip"})
    text = text.replace('candidates = ["mouth"]', 'candidates = ["chocolate_bowl"]')
    with pytest.raises(InputError) as info:
        load_taskgraph(write(tmp_path, "layered", text))
    message = str(info.value)
    path = ["food", *(f"a{i}" for i in range(1, MAX_LAYERS + 1)), "feed"]
    assert message.endswith(
        f"the graph repeats but ends holding an object (after {' -> '.join(path)})"
    )
    assert "stages[63].action" in message


# --- small random graphs: the dynamic programmes against every path, listed --------------


def all_paths(graph: TaskGraph) -> list[list[str]]:
    """Every path from the start to an end stage, in the order of the next lists."""
    out: list[list[str]] = []

    def walk(path: list[str]) -> None:
        nxt = graph.stages[path[-1]].next
        if not nxt:
            out.append(path)
        for n in nxt:
            walk([*path, n])

    walk([graph.start])
    return out


def brute_held_problem(graph: TaskGraph) -> HeldProblem | None:
    """The held-object check as it was: every path walked in order, the first fault."""
    for path in all_paths(graph):
        held = False
        for i, name in enumerate(path):
            act = action(graph.stages[name].action)
            if act.needs_held != held:
                return HeldProblem(tuple(path[: i + 1]), held)
            held = held if act.holds_after is None else act.holds_after
        if graph.repeat == "until_consumed" and held:
            return HeldProblem(tuple(path), held, ends_held=True)
    return None


@st.composite
def small_dags(draw: st.DrawFn, max_stages: int = 9, reachable: bool = False) -> TaskGraph:
    """A random DAG over stages s0..s<n-1> (edges to later stages only, in random order);
    actions either random or mostly consistent with what a first predecessor leaves held.
    ``reachable``: every stage has a predecessor."""
    n = draw(st.integers(1, max_stages))
    nexts: list[list[int]] = []
    for i in range(n):
        later = st.lists(st.integers(i + 1, n - 1), unique=True, max_size=3)
        nexts.append(draw(later) if i < n - 1 else [])
    if reachable:
        for j in range(1, n):
            if not any(j in nx for nx in nexts[:j]):
                nexts[draw(st.integers(0, j - 1))].append(j)
    consistent = draw(st.booleans())
    actions: list[str] = []
    arrive: dict[int, bool] = {0: False}
    for i in range(n):
        if consistent:
            need = arrive.get(i, False)
            options = [a for a in ACTIONS if action(a).needs_held == need]
            act = draw(st.sampled_from(options))
            after = action(act).holds_after
            for j in nexts[i]:
                arrive.setdefault(j, need if after is None else after)
        else:
            act = draw(st.sampled_from(ACTIONS))
        actions.append(act)
    stages = {
        f"s{i}": Stage(f"s{i}", (f"c{i}",), actions[i], tuple(f"s{j}" for j in nexts[i]))
        for i in range(n)
    }
    repeat = draw(st.sampled_from(["once", "until_consumed"]))
    return TaskGraph("g", "scene", stages, repeat)


@settings(max_examples=400)
@given(small_dags())
def test_path_count_and_held_check_agree_with_every_path(graph: TaskGraph) -> None:
    paths = all_paths(graph)
    assert graph.path_count() == len(paths)
    order = topological_order(graph.stages)
    position = {n: i for i, n in enumerate(order)}
    assert all(position[s.name] < position[n] for s in graph.stages.values() for n in s.next)
    assert held_problem(graph) == brute_held_problem(graph)


#: cluttered has 8 movable objects: a stage each, so alternatives never share a candidate.
CLUTTERED = load_scene("cluttered")


@settings(max_examples=150)
@given(small_dags(max_stages=len(CLUTTERED.movable), reachable=True))
def test_check_refuses_exactly_the_graphs_with_a_bad_path(
    tmp_path_factory: pytest.TempPathFactory, graph: TaskGraph
) -> None:
    objects = CLUTTERED.movable
    text = f'schema_version = 1\nname = "g"\nscene = "cluttered"\nrepeat = "{graph.repeat}"\n\n'
    for i, stage in enumerate(graph.stages.values()):
        text += _stage(stage.name, [objects[i]], stage.action, list(stage.next))
    graph_file = write(tmp_path_factory.mktemp("g"), "g", text)
    expected = brute_held_problem(graph)
    if expected is None and (graph.repeat == "once" or graph.stages["s0"].action == "pick"):
        loaded, _ = load_taskgraph(graph_file, CLUTTERED)
        assert loaded.path_count() == len(all_paths(graph))
        return
    with pytest.raises(InputError) as info:
        load_taskgraph(graph_file, CLUTTERED)
    message = str(info.value)
    if expected is None:
        assert message.endswith("a repeated graph must start with 'pick' (what it consumes)")
        return
    assert f"stages[{int(expected.path[-1][1:])}].action" in message
    if expected.ends_held:
        assert message.endswith(f"(after {' -> '.join(expected.path)})")
    else:
        before = " -> ".join(expected.path[:-1]) or "the start"
        act = graph.stages[expected.path[-1]].action
        assert f"'{act}' after {before}: the gripper" in message
    assert_is_path(graph, list(expected.path))

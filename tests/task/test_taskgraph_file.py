"""Task-graph files: the shipped ones validate; each malformed case is one clear line."""

from __future__ import annotations

from pathlib import Path

import pytest

from legws_daemon.errors import InputError
from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph, taskgraphs_dir

GOOD = """schema_version = 1
name = "{name}"
scene = "feeding"

[[stages]]
name = "food"
candidates = ["strawberry", "grape", "brownie"]
action = "pick"
next = ["dip", "feed"]

[[stages]]
name = "dip"
candidates = ["chocolate_bowl", "sprinkles_bowl"]
action = "dip"
next = ["feed"]

[[stages]]
name = "feed"
candidates = ["mouth"]
action = "feed"
"""


def write(tmp_path: Path, text: str, name: str = "g") -> Path:
    p = tmp_path / f"{name}.toml"
    p.write_text(text.replace("{name}", name))
    return p


@pytest.mark.parametrize("name", ["tea", "lego", "feeding"])
def test_shipped_graphs_validate(name: str) -> None:
    graph, scene = load_taskgraph(resolve_taskgraph(name))
    assert graph.name == name
    assert scene.name == graph.scene
    assert graph.path_count() >= 1


def test_every_file_in_taskgraphs_is_shipped_and_valid() -> None:
    names = sorted(p.stem for p in taskgraphs_dir().glob("*.toml"))
    assert names == ["feeding", "lego", "tea"]


def test_choices_and_optional_steps(tmp_path: Path) -> None:
    graph, _ = load_taskgraph(write(tmp_path, GOOD))
    assert graph.path_count() == 2  # food -> dip -> feed, food -> feed
    assert graph.order() == ["food", "dip", "feed"]
    assert [s.name for s in graph.successors("food")] == ["dip", "feed"]


@pytest.mark.parametrize(
    ("old", "new", "line", "field", "message"),
    [
        ('"grape", "brownie"]', '"grape", "mug"]', 7, "stages[0].candidates[2]",
         "unknown object or place 'mug'"),
        ('next = ["feed"]', 'next = ["food"]', 15, "stages[1].next", "cycle food -> dip -> food"),
        ('next = ["dip", "feed"]', 'next = ["feed"]', 12, "stages[1].name",
         "'dip' cannot be reached from 'food'"),
        ('["chocolate_bowl", "sprinkles_bowl"]', "[]", 13, "stages[1].candidates",
         "at least 1 item"),
        ('candidates = ["mouth"]', 'candidates = ["mouth", "chocolate_bowl"]', 9,
         "stages[0].next", "share candidate 'chocolate_bowl'"),
        ('action = "pick"', 'action = "place"', 8, "stages[0].action",
         "'place' after the start: the gripper holds nothing there"),
        ('next = ["feed"]', 'next = ["feed", "nowhere"]', 15, "stages[1].next[1]",
         "unknown stage 'nowhere'"),
        ('action = "dip"', 'action = "stir"', 14, "stages[1].action", "'pick'"),
        ('candidates = ["mouth"]', 'candidates = ["mouth", "mouth"]', 19,
         "stages[2].candidates[1]", "listed twice"),
    ],
)  # fmt: skip
def test_malformed_graphs_name_line_and_field(
    tmp_path: Path, old: str, new: str, line: int, field: str, message: str
) -> None:
    assert old in GOOD
    p = write(tmp_path, GOOD.replace(old, new, 1))
    with pytest.raises(InputError) as info:
        load_taskgraph(p)
    text = str(info.value)
    assert "\n" not in text
    assert field in text
    assert message in text
    if "at least 1" not in message and "'pick'" not in message:  # schema errors: no line
        assert text.startswith(f"{p}:{line}: ")


def test_more_malformed_cases(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"expected 'other' \(the file's name\)"):
        load_taskgraph(write(tmp_path, GOOD.replace("{name}", "g"), "other"))
    with pytest.raises(InputError, match="unknown scene 'nope'"):
        load_taskgraph(write(tmp_path, GOOD.replace('scene = "feeding"', 'scene = "nope"')))
    bad_toml = write(tmp_path, GOOD.replace('action = "feed"', "action = feed"))
    with pytest.raises(InputError, match="line 20"):
        load_taskgraph(bad_toml)
    repeat = GOOD.replace('scene = "feeding"', 'scene = "feeding"\nrepeat = "until_consumed"')
    graph, _ = load_taskgraph(write(tmp_path, repeat))
    assert graph.repeat == "until_consumed"
    place_pick = GOOD.replace('"grape", "brownie"]', '"grape", "mouth"]')
    with pytest.raises(InputError, match="'mouth' is a place"):
        load_taskgraph(write(tmp_path, place_pick))
    fixed = GOOD.replace('scene = "feeding"', 'scene = "feeding"\nfixed = ["spoon"]')
    with pytest.raises(InputError, match=r"fixed\[0\].*unknown object 'spoon'"):
        load_taskgraph(write(tmp_path, fixed))
    with pytest.raises(InputError, match="no such file"):
        load_taskgraph(tmp_path / "missing.toml")
    with pytest.raises(InputError, match="unknown task graph 'nope'; known: feeding, lego, tea"):
        resolve_taskgraph("nope")


def test_single_candidate_stage_is_legal(tmp_path: Path) -> None:
    graph, _ = load_taskgraph(write(tmp_path, GOOD))
    assert graph.stages["feed"].candidates == ("mouth",)

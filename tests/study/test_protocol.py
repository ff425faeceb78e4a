"""Study protocol files: the shipped ones load; errors name the file, the line and the field."""

from __future__ import annotations

from pathlib import Path

import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.validation import error_lines
from legws_daemon.study.protocol import load_protocol, resolve_protocol, studies_dir

GOOD = """\
schema_version = 1
name = "{name}"
title = "A test study"
seed = 3

[design]
counterbalance = "latin"
trials_per_condition = 4
practice_trials = 1

[tasks.pick]
scene = "breakfast"

[tasks.tea]
taskgraph = "tea"

[[conditions]]
name = "random"
task = "pick"
layout = "random"

[[conditions]]
name = "optimised"
task = "tea"
layout = "optimised"
assist = "blend"
"""


def _write(tmp_path: Path, text: str, name: str = "study") -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(text.replace("{name}", name), encoding="utf-8")
    return path


@pytest.mark.parametrize("name", sorted(p.stem for p in studies_dir().glob("*.toml")))
def test_every_shipped_protocol_loads(name: str) -> None:
    p = load_protocol(name)
    assert p.name == name and len(p.condition_names) >= 2
    assert len(p.sha256) == 64


def test_the_paper_question_is_shipped() -> None:
    p = load_protocol("layouts_tea")
    layouts = {c.layout for c in p.spec.conditions}
    assert {"random", "optimised"} <= layouts
    assert {t.kind for t in p.tasks.values()} == {"taskgraph"}


def test_a_good_protocol_loads_its_tasks(tmp_path: Path) -> None:
    p = load_protocol(_write(tmp_path, GOOD))
    assert p.tasks["pick"].kind == "scene" and p.tasks["pick"].source == "breakfast"
    assert p.tasks["tea"].kind == "taskgraph" and p.tasks["tea"].scene.name == "tea"
    assert p.condition("optimised").assist == "blend"
    assert p.spec.design.break_every == 1  # the defaults
    assert p.spec.questionnaires.nasa_tlx


CASES = [
    ('layout = "random"', 'layout = "randm"', ":20: conditions[0].layout: Input should be"),
    ('task = "pick"', 'task = "pik"',
     ":19: conditions[0].task: unknown task 'pik'; did you mean 'pick'?"),
    ("trials_per_condition = 4", "trials_per_condition = 0",
     ":8: design.trials_per_condition: Input should be greater than or equal to 1"),
    ('scene = "breakfast"', 'scene = "brekfast"',
     ":12: tasks.pick.scene: unknown scene 'brekfast'; did you mean 'breakfast'?"),
    ('taskgraph = "tea"', 'scene = "tea"\ntaskgraph = "tea"',
     ":14: tasks.tea: expected exactly one of 'scene' or 'taskgraph'"),
    ('counterbalance = "latin"', 'counterbalance = "abba"',
     ":7: design.counterbalance: Input should be 'latin', 'williams' or 'fixed'"),
    ('name = "optimised"', 'name = "random"',
     ":23: conditions[1].name: condition 'random' is named twice"),
]  # fmt: skip


@pytest.mark.parametrize(("old", "new", "expected"), CASES)
def test_an_error_names_the_file_line_and_field(
    tmp_path: Path, old: str, new: str, expected: str
) -> None:
    path = _write(tmp_path, GOOD.replace(old, new, 1))
    with pytest.raises(InputError) as err:
        load_protocol(path)
    lines = error_lines(err.value)
    assert any(line.startswith(str(path)) and expected in line for line in lines), lines


def test_a_task_no_condition_uses_and_a_wrong_name_are_both_reported(tmp_path: Path) -> None:
    text = GOOD.replace('task = "tea"', 'task = "pick"')
    path = _write(tmp_path, text, "other")
    path = path.rename(tmp_path / "renamed.toml")
    with pytest.raises(InputError) as err:
        load_protocol(path)
    lines = error_lines(err.value)
    assert len(lines) == 2, lines
    assert "name: expected 'renamed' (the file's name), got 'other'" in lines[0]
    assert ":14: tasks.tea: task 'tea' is used by no condition" in lines[1]


def test_an_unknown_protocol_name_lists_the_shipped_ones() -> None:
    with pytest.raises(InputError, match=r"did you mean 'layouts_tea'.*known: .*assist_policies"):
        resolve_protocol("layout_tea")


def test_every_error_of_a_file_is_reported_in_line_order(tmp_path: Path) -> None:
    text = GOOD.replace('scene = "breakfast"', 'scene = "brekfast"').replace(
        'task = "pick"', 'task = "pik"'
    )
    with pytest.raises(InputError) as err:
        load_protocol(_write(tmp_path, text))
    lines = error_lines(err.value)
    assert len(lines) == 2, lines  # the typo is not also "task 'pick' is used by no condition"
    assert ":12: tasks.pick.scene: unknown scene 'brekfast'" in lines[0]
    assert ":19: conditions[0].task: unknown task 'pik'" in lines[1]


def test_an_error_inside_a_task_graph_file_names_that_file(tmp_path: Path) -> None:
    graph = tmp_path / "mytea.toml"
    graph.write_text(
        (Path(__file__).parents[2] / "taskgraphs" / "tea.toml")
        .read_text()
        .replace('name = "tea"', 'name = "mytea"')
        .replace('"cup"]', '"mug"]', 1),
        encoding="utf-8",
    )
    text = GOOD.replace('taskgraph = "tea"', f'taskgraph = "{graph}"')
    with pytest.raises(InputError) as err:
        load_protocol(_write(tmp_path, text))
    line = error_lines(err.value)[0]
    # the task graph's own error (its path, cut in the middle to fit one line), at the
    # protocol's field
    assert ":15: tasks.tea.taskgraph: " in line
    assert "unknown object or place 'mug' in scene 'tea'" in line

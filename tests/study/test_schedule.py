"""Schedules: balanced orders in blocks, seeded, every step of a session in its place."""

from __future__ import annotations

import csv
import io
from collections import Counter

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.study.counterbalance import balance
from legws_daemon.study.protocol import Protocol, load_protocol
from legws_daemon.study.schedule import make_schedule, pseudonyms


@pytest.fixture(scope="module")
def tea() -> Protocol:
    return load_protocol("layouts_tea")


@pytest.fixture(scope="module")
def assist() -> Protocol:
    return load_protocol("assist_policies")


def test_pseudonyms_are_numbered_and_padded() -> None:
    assert pseudonyms(3) == ["P01", "P02", "P03"]
    assert pseudonyms(120)[-1] == "P120" and pseudonyms(120)[0] == "P001"


def test_a_williams_schedule_of_twelve_is_balanced_in_positions_and_neighbours(
    tea: Protocol,
) -> None:
    s = make_schedule(tea, 12)
    assert s.problems == ()
    names = list(s.conditions)
    orders = [[names.index(c) for c in o] for o in s.orders.values()]
    b = balance(orders, 3)
    assert all(n == 4 for row in b.positions for n in row)
    assert set(b.pairs.values()) == {4} and len(b.pairs) == 6  # twice per six rows
    # each block of six participants holds the six rows once
    for start in (0, 6):
        block = {tuple(o) for o in orders[start : start + 6]}
        assert block == {tuple(r) for r in s.rows}


@settings(max_examples=10)
@given(st.integers(1, 30))
def test_the_schedule_is_balanced_exactly_when_whole_blocks_are_planned(n: int) -> None:
    p = load_protocol("assist_policies")
    s = make_schedule(p, n)
    assert (s.problems == ()) == (n % len(s.rows) == 0)


def test_the_same_protocol_gives_the_same_schedule_and_another_seed_another(
    tea: Protocol,
) -> None:
    a, b = make_schedule(tea, 6), make_schedule(tea, 6)
    assert a.plan_json() == b.plan_json()
    other = Protocol(tea.spec.model_copy(update={"seed": 1}), tea.tasks, tea.source, tea.sha256)
    assert make_schedule(other, 6).orders != a.orders


def test_a_session_runs_calibration_practice_trials_questionnaires_and_breaks(
    tea: Protocol,
) -> None:
    s = make_schedule(tea, 6)
    steps = s.steps["P03"]
    kinds = [x.kind for x in steps]
    d = tea.spec.design
    per_condition = ["practice"] * d.practice_per_condition + ["trial"] * d.trials_per_condition
    expected = ["calibration"] + ["practice"] * d.practice_trials
    for k in range(3):
        expected += per_condition + ["questionnaire"] + (["break"] if k < 2 else [])
    assert kinds == expected
    assert [x.index for x in steps] == list(range(1, len(steps) + 1))
    trials = [x for x in steps if x.kind == "trial"]
    assert [x.condition for x in trials[:: d.trials_per_condition]] == list(s.orders["P03"])
    assert all(x.task_kind == "taskgraph" and x.source == "tea" for x in trials)
    # the tea graph: a tea bag, then a snack (the cup and the plate are single candidates)
    teas = {"black_tea", "green_tea", "chamomile_tea"}
    assert all(len(x.targets) == 2 and x.targets[0] in teas for x in trials)
    first = next(x for x in steps if x.kind == "practice")
    assert first.condition is None and first.layout == "shipped"


def test_a_conditions_first_targets_come_equally_often(assist: Protocol) -> None:
    s = make_schedule(assist, 4)
    for person, steps in s.steps.items():
        for cond in s.conditions:
            got = Counter(x.targets[0] for x in steps if x.kind == "trial" and x.condition == cond)
            # 16 trials over the 8 goals of the cluttered scene: each twice
            assert set(got.values()) == {2} and len(got) == 8, (person, cond)


def test_random_layouts_are_the_same_for_every_participant(tea: Protocol) -> None:
    s = make_schedule(tea, 6)

    def seeds(person: str) -> dict[tuple[str | None, int | None], int | None]:
        return {(x.condition, x.trial): x.layout_seed for x in s.steps[person] if x.kind == "trial"}

    assert seeds("P01") == seeds("P05")
    assert len(set(seeds("P01").values())) == 18  # a new layout for every trial


def test_the_lego_walk_sorts_every_brick_once() -> None:
    import numpy as np

    from legws_daemon.study.protocol import Task
    from legws_daemon.study.schedule import trial_targets
    from legws_daemon.task.taskgraph_file import load_taskgraph, resolve_taskgraph

    graph, scene = load_taskgraph(resolve_taskgraph("lego"))
    targets = trial_targets(Task("lego", scene, graph), "green_brick", np.random.default_rng(0))
    bricks = [t for t in targets if t.endswith("_brick")]
    assert bricks[0] == "green_brick" and sorted(bricks) == sorted(scene.goal_names)
    assert len(targets) == 8 and all(t.startswith("bin_") for t in targets[1::2])


def test_the_csv_has_one_row_per_step(tea: Protocol) -> None:
    s = make_schedule(tea, 6)
    rows = list(csv.DictReader(io.StringIO(s.csv_text())))
    assert len(rows) == sum(len(v) for v in s.steps.values())
    trial = next(r for r in rows if r["kind"] == "trial")
    assert trial["participant"] == "P01" and ";" in trial["targets"]
    assert int(trial["layout_seed"]) >= 0

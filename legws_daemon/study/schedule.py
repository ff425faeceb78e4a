"""A study's schedule: each participant's order of conditions and every step of their session.

:func:`make_schedule` turns a protocol and a number of participants into a
:class:`Schedule`. Participants are pseudonyms ``P01 .. PNN``. The design's rows
(:mod:`~legws_daemon.study.counterbalance`) go to the participants in blocks of as many
participants as there are rows; inside each block the rows are shuffled (seeded by the
protocol's ``seed``), so a complete block balances by itself and a study cut short after a
block stays balanced.

A participant's session is a list of :class:`Step`: the calibration (method.md §10), the
practice trials, then for each condition in their order its practice trials, its trials,
the questionnaire and, every ``break_every`` conditions, a break. Each trial names its
layout (source and seed) and the objects the participant is asked to reach (*targets*):

- layout seeds depend on the condition and the trial number, not on the participant: every
  participant sees the same set of random layouts in a condition (layout is then a crossed
  factor the analysis can hold apart);
- a scene task's trial has one target; over a condition's trials the goals come equally
  often (as nearly as the number of trials allows), in an order drawn for each participant;
- a task graph's trial walks the graph from its first stage: a target at every stage with
  more than one candidate (the first choice balanced like a scene's goals, later ones drawn),
  the next stage drawn among its successors; a graph that repeats until its candidates are
  used up walks until they are.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np

from legws_daemon.study.counterbalance import Design, balance, design_rows, problems
from legws_daemon.study.protocol import Protocol, Task

StepKind = Literal["calibration", "practice", "trial", "questionnaire", "break"]
#: Largest number of steps a task graph's walk may take (the graph checks bound it far below).
MAX_WALK = 256


@dataclass(frozen=True, slots=True)
class Step:
    """One step of a participant's session.

    Attributes:
        participant: the pseudonym.
        index: 1-based place in the session.
        kind: what the step is.
        condition: the condition (``None`` for calibration, a break and the first practice).
        position: the condition's place in the participant's order, 1-based (or ``None``).
        trial: 1-based trial number within the condition (practice trials count apart).
        task, task_kind: the protocol's task and whether it is a ``scene`` or ``taskgraph``.
        source: the scene's or task graph's name.
        layout: the layout source (``shipped``, ``random``, ...).
        layout_seed: the seed of a random layout (and of an optimised one's search).
        objective: the optimiser's objective for optimised layouts.
        assist: the assistance policy.
        targets: the objects the participant is asked to reach, in order.
        break_s: a break's suggested length, s.
    """

    participant: str
    index: int
    kind: StepKind
    condition: str | None = None
    position: int | None = None
    trial: int | None = None
    task: str | None = None
    task_kind: str | None = None
    source: str | None = None
    layout: str | None = None
    layout_seed: int | None = None
    objective: str | None = None
    assist: str | None = None
    targets: tuple[str, ...] = ()
    break_s: int | None = None

    def as_data(self) -> dict[str, Any]:
        out = asdict(self)
        out["targets"] = list(self.targets)
        return out


@dataclass(frozen=True, slots=True)
class Schedule:
    """A study's plan.

    Attributes:
        protocol: the protocol's name; ``protocol_sha256`` its text's hash.
        design: the counterbalancing design.
        conditions: the condition names, in the protocol's order.
        rows: the design's rows (condition indices).
        orders: participant -> condition names in their order.
        steps: participant -> their session.
        problems: where the schedule is not balanced (``[]``: balanced).
    """

    protocol: str
    protocol_sha256: str
    design: Design
    seed: int
    conditions: tuple[str, ...]
    rows: tuple[tuple[int, ...], ...]
    orders: dict[str, tuple[str, ...]]
    steps: dict[str, tuple[Step, ...]]
    problems: tuple[str, ...]

    def schedule_json(self) -> dict[str, Any]:
        """``schedule.json``: ``{"conditions": [...], "participants": {"P01": [...]}}``."""
        return {
            "conditions": list(self.conditions),
            "participants": {p: list(order) for p, order in self.orders.items()},
        }

    def plan_json(self) -> dict[str, Any]:
        """``plan.json``: everything, for ``legws study run`` and for the methods section."""
        index = {c: i for i, c in enumerate(self.conditions)}
        counted = balance([[index[c] for c in o] for o in self.orders.values()], len(index))
        return {
            "schema": 1,
            "protocol": self.protocol,
            "protocol_sha256": self.protocol_sha256,
            "design": self.design,
            "seed": self.seed,
            "conditions": list(self.conditions),
            "rows": [[self.conditions[i] for i in row] for row in self.rows],
            "balanced": not self.problems,
            "problems": list(self.problems),
            "positions": {c: list(counted.positions[i]) for i, c in enumerate(self.conditions)},
            "neighbours": {
                f"{self.conditions[a]}>{self.conditions[b]}": n
                for (a, b), n in sorted(counted.pairs.items())
            },
            "participants": {p: [s.as_data() for s in steps] for p, steps in self.steps.items()},
        }

    def csv_text(self) -> str:
        """``schedule.csv``: one row per step of every session (targets joined by ``;``)."""
        columns = list(Step.__dataclass_fields__)
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
        writer.writeheader()
        for steps in self.steps.values():
            for s in steps:
                row = s.as_data()
                row["targets"] = ";".join(s.targets)
                writer.writerow({k: "" if v is None else v for k, v in row.items()})
        return buf.getvalue()


def pseudonyms(n: int) -> list[str]:
    """``P01 .. PNN`` (three digits from 100 participants on)."""
    width = max(2, len(str(n)))
    return [f"P{k:0{width}d}" for k in range(1, n + 1)]


def _rng(seed: int, *keys: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, *keys]))


def _seed(seed: int, *keys: int) -> int:
    return int(np.random.SeedSequence([seed, *keys]).generate_state(1)[0])


def _balanced_draws(choices: Sequence[str], n: int, rng: np.random.Generator) -> list[str]:
    """``n`` of ``choices``, each as often as ``n`` allows (rounds of a shuffled list)."""
    out: list[str] = []
    while len(out) < n:
        out += [choices[i] for i in rng.permutation(len(choices))]
    return out[:n]


def trial_targets(task: Task, first: str | None, rng: np.random.Generator) -> tuple[str, ...]:
    """The objects one trial of ``task`` asks for (``first``: the first choice's target)."""
    if task.graph is None:
        assert first is not None
        return (first,)
    graph = task.graph
    used: set[str] = set()
    out: list[str] = []
    name: str | None = graph.start
    first_pending = True
    for _ in range(MAX_WALK):
        if name is None:
            if graph.repeat != "until_consumed":
                break
            left = [c for c in graph.stages[graph.start].candidates if c not in used]
            if not left:
                break
            name = graph.start
        stage = graph.stages[name]
        candidates = [c for c in stage.candidates if c not in used]
        if not candidates:
            break
        if len(stage.candidates) > 1:  # a choice (the last of a repeated graph's too)
            if first_pending and first is not None and first in candidates:
                pick = first
            else:
                pick = candidates[int(rng.integers(len(candidates)))]
            first_pending = False
            out.append(pick)
            if stage.action == "pick" and graph.repeat == "until_consumed":
                used.add(pick)
        nxt = stage.next
        name = nxt[int(rng.integers(len(nxt)))] if nxt else None
    return tuple(out)


def _first_choices(task: Task) -> list[str]:
    """The candidates of a task's first choice: a scene's goals, or the first stage of a task
    graph's walk with more than one candidate."""
    if task.graph is None:
        return list(task.scene.goal_names)
    name: str | None = task.graph.start
    while name is not None:
        stage = task.graph.stages[name]
        if len(stage.candidates) > 1:
            return list(stage.candidates)
        name = stage.next[0] if stage.next else None
    return []


def make_schedule(protocol: Protocol, participants: int) -> Schedule:
    """The schedule of ``participants`` participants (see the module's text)."""
    spec = protocol.spec
    design = spec.design
    names = protocol.condition_names
    rows = design_rows(design.counterbalance, len(names))
    people = pseudonyms(participants)
    assigned: list[list[int]] = []
    for block in range(0, participants, len(rows)):
        perm = _rng(spec.seed, 1, block // len(rows)).permutation(len(rows))
        assigned += [rows[int(i)] for i in perm]
    orders = {p: tuple(names[c] for c in assigned[k]) for k, p in enumerate(people)}
    steps: dict[str, tuple[Step, ...]] = {}
    for k, person in enumerate(people):
        steps[person] = tuple(_session(protocol, person, k, orders[person]))
    found = problems(assigned[:participants], names, design.counterbalance)
    return Schedule(
        protocol=spec.name,
        protocol_sha256=protocol.sha256,
        design=design.counterbalance,
        seed=spec.seed,
        conditions=tuple(names),
        rows=tuple(tuple(r) for r in rows),
        orders=orders,
        steps=steps,
        problems=tuple(found),
    )


def _session(protocol: Protocol, person: str, k: int, order: Sequence[str]) -> list[Step]:
    spec = protocol.spec
    design = spec.design
    out: list[Step] = []

    def add(kind: StepKind, **fields: Any) -> None:
        out.append(Step(person, len(out) + 1, kind, **fields))

    def trials(kind: StepKind, ci: int, position: int | None, count: int, code: int) -> None:
        cond = spec.conditions[ci]
        task = protocol.tasks[cond.task]
        rng = _rng(spec.seed, 2, k, ci, code)
        firsts = _balanced_draws(_first_choices(task), count, rng) if _first_choices(task) else []
        for t in range(count):
            first = firsts[t] if firsts else None
            add(
                kind,
                condition=cond.name if position is not None else None,
                position=position,
                trial=t + 1,
                task=task.name,
                task_kind=task.kind,
                source=task.source,
                layout=cond.layout if position is not None else "shipped",
                layout_seed=_seed(spec.seed, 3, ci, code, t),
                objective=cond.objective if position is not None else None,
                # the first practice trials: the joystick and the commit, before any condition
                assist=cond.assist if position is not None else "commit",
                targets=trial_targets(task, first, rng),
            )

    if design.calibrate:
        add("calibration")
    first_ci = protocol.condition_names.index(order[0])
    trials("practice", first_ci, None, design.practice_trials, 0)
    for pos, name in enumerate(order, start=1):
        ci = protocol.condition_names.index(name)
        trials("practice", ci, pos, design.practice_per_condition, 1)
        trials("trial", ci, pos, design.trials_per_condition, 2)
        add("questionnaire", condition=name, position=pos)
        if design.break_every and pos % design.break_every == 0 and pos < len(order):
            add("break", position=pos, break_s=design.break_s)
    return out

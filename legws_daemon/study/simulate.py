"""Simulated participants: whole studies on the stand-in, in simulated time.

Each participant is drawn from a population (:mod:`.population`) and runs their planned
session (:mod:`.schedule`) on what the daemon runs — its
:class:`~legws_daemon.autonomy.controller.Controller` driving the MuJoCo stand-in, ticked as
fast as it computes (the clock injected, nothing paced):

- **calibration** (method.md §10): the participant's reaches to the calibration targets
  (:func:`~legws_daemon.sim.reaches.simulate_reaches`, their true model), written as a
  teleoperation trace, and their operator model *fitted* from it
  (:func:`~legws_daemon.core.operator_fit.fit_operator`) — the study never sees the true
  model, only what it measured, as with a person; the operator file is what
  ``optimised_for_operator`` designs for and every certificate "for the person" uses;
- **trials**: a scene task's trial is the protocol's pick
  (:meth:`~legws_daemon.sim.protocol.Evaluator.pick`) of the asked-for goal; a task graph's
  trial runs the whole graph, the participant going for the asked-for object at each choice
  (:class:`~legws_daemon.joystick.sim_user.SimUser` with the model); before the first push
  the participant hesitates (the stick held still) for their hesitation of that trial;
- **frames**: every trial's per-tick frames (the EE, the axes sent, the mode) are recorded
  as it runs and written to ``PXX/frames/step-NNN.parquet`` (:mod:`.frames`), the trial
  table's ``frames`` column;
- **questionnaires**: each NASA-TLX subscale the participant's baseline plus the condition's
  planted effect plus noise, rounded to the scale's steps of 5 and clipped to 0-100; each
  Likert item likewise, rounded to a point of the scale.

A planted effect of a condition (the population's ``effects``) shifts the hesitation, scales
the operator's speed and shifts the answers in that condition: a known effect the analysis
must recover.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from legws_daemon.autonomy.events import (
    AssistFailed,
    Cancel,
    Commit,
    Fault,
    Override,
    TaskDone,
)
from legws_daemon.autonomy.inputs import OperatorInput
from legws_daemon.autonomy.modes import Mode
from legws_daemon.core.arbitration import AssistPolicy
from legws_daemon.core.operator import SPEED_RANGE, OperatorModel
from legws_daemon.core.operator_fit import fit_operator
from legws_daemon.core.params import Params
from legws_daemon.core.user_model import SimulatedUser
from legws_daemon.errors import InputError
from legws_daemon.formats.files import output_folder, write_atomic
from legws_daemon.formats.operator_file import OperatorFile
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.formats.trace import Segment, write_trace
from legws_daemon.joystick.sim_user import SimUser, UserView
from legws_daemon.sim.protocol import (
    ASSIST_LIMIT_S,
    TIMEOUT_S,
    Evaluator,
    SimStand,
    TickCallback,
    stand_in_profile,
)
from legws_daemon.sim.reaches import simulate_reaches
from legws_daemon.study.certificates import trial_certificates
from legws_daemon.study.frames import FrameRecorder, frames_path, write_frames
from legws_daemon.study.layouts import Layouts, TrialLayout
from legws_daemon.study.outcome import Outcome
from legws_daemon.study.population import Participant, Population
from legws_daemon.study.protocol import NASA_TLX, ConditionSpec, Protocol, Task
from legws_daemon.study.rows import trial_row
from legws_daemon.study.schedule import Schedule, Step
from legws_daemon.study.table import write_dictionary, write_table

#: Bootstrap resamples of a simulated calibration's fit (the intervals of the operator file).
FIT_RESAMPLES = 200


def with_effect(model: OperatorModel, speed_scale: float) -> OperatorModel:
    """``model`` with its speed scaled (kept in the model's range)."""
    lo, hi = SPEED_RANGE
    return replace(model, speed=min(hi, max(lo, model.speed * speed_scale)))


def calibrate(
    participant: Participant, reaches: int, params: Params, folder: Path, seed: int
) -> OperatorFile:
    """The participant's calibration: their reaches, the trace, the fitted operator file
    (``folder/operator.json``, ``folder/calibration.trace.jsonl``)."""
    rng = np.random.default_rng([seed, 0xCA1])
    segments = simulate_reaches(SimulatedUser(participant.model, clip=True), reaches, rng, params)
    write_trace(
        folder / "calibration.trace.jsonl",
        [Segment(i, ee, u, g) for i, (ee, u, g) in enumerate(segments)],
    )
    fit = fit_operator(segments, params, resamples=FIT_RESAMPLES, seed=seed)
    record = OperatorFile.from_fit(
        fit, participant.pseudonym, {"traces": ["calibration.trace.jsonl"], "simulated": True}
    )
    record.write(folder / "operator.json")
    return record


def answers(
    participant: Participant,
    population: Population,
    condition: str,
    likert_items: int,
    points: int,
    rng: np.random.Generator,
) -> dict[str, Any]:
    """The participant's questionnaire after ``condition`` (see the module's text)."""
    a = population.spec.answers
    effect = population.effect(condition)
    out: dict[str, Any] = {}
    for key, _ in NASA_TLX:
        raw = participant.tlx + effect.tlx + a.tlx.noise * float(rng.standard_normal())
        out[f"tlx_{key}"] = float(min(100.0, max(0.0, 5.0 * round(raw / 5.0))))
    out["tlx_raw"] = float(np.mean([out[f"tlx_{k}"] for k, _ in NASA_TLX]))
    for k in range(1, likert_items + 1):
        raw = participant.likert + effect.likert + a.likert.noise * float(rng.standard_normal())
        out[f"likert_{k}"] = int(min(points, max(1, round(raw))))
    return out


def run_graph_trial(
    stand: SimStand,
    task: Task,
    layout: TrialLayout,
    targets: tuple[str, ...],
    model: OperatorModel,
    hesitation: float,
    params: Params,
    rng: np.random.Generator,
    on_tick: TickCallback | None = None,
) -> Outcome:
    """One trial of a task graph: the whole graph, the participant going for ``targets``
    (``on_tick``: called every control tick, as :meth:`Evaluator.pick`'s)."""
    c, clock = stand.controller, stand.clock
    assert task.graph is not None
    c.load(task.scene, layout.layout, task.graph, layout.plan)
    adapter = stand.stand_in
    adapter.reset_arm()
    c.restart_task()
    stand.events.clear()
    user = SimUser(list(targets), model.sigma, params.v_max, rng, operator=model, dt=params.dt)
    out = Outcome()
    start = clock.ticks
    decision_started = 0.0
    choice = 0
    limit = TIMEOUT_S + ASSIST_LIMIT_S
    while True:
        now = (clock.ticks - start) * clock.dt
        if c.mode in (Mode.IDLE, Mode.FAULT) or out.completed or out.failure:
            break
        if c.mode == Mode.TELEOP and now - max(decision_started, hesitation) >= TIMEOUT_S:
            out.failure = f"no_commit: none within {TIMEOUT_S:g} s of a decision"
            break
        if now - decision_started >= limit + hesitation:
            out.failure = f"limit: still in '{c.mode}' after {now - decision_started:.0f} s"
            break
        state = adapter.read_state()
        if now < hesitation:
            axes, confirm, cancel = np.zeros(3), False, False
        else:
            targets_now = {t.name: t.position for t in c.stage.targets}
            view = UserView(c.mode.value, c.decisions, c.stage.name, state.ee_position, targets_now)
            act = user.act(view, now)
            axes, confirm, cancel = act.axes, act.confirm, act.cancel
        rec = c.tick(OperatorInput(axes, confirm, cancel, clock()))
        if on_tick is not None:
            on_tick(clock.ticks - start, state.ee_position, axes, rec.mode.value)
        clock.advance()
        out.effort_s += float(np.linalg.norm(axes)) * clock.dt
        t = (clock.ticks - start) * clock.dt
        if out.time_to_grasp_s is None and adapter.held is not None:
            out.time_to_grasp_s = t
        for event in stand.events:
            match event:
                case Commit():
                    decision_started = t
                    if event.single:
                        continue
                    out.chosen.append(event.goal)
                    asked = targets[choice] if choice < len(targets) else None
                    choice += 1
                    if event.goal != asked:
                        out.wrong += 1
                    if event.confirmed:
                        out.confirms += 1
                    else:
                        out.commit_times.append(event.seconds)
                case Cancel():
                    out.cancels += 1
                case Override():
                    out.overrides += 1
                case TaskDone():
                    out.completed, out.time_to_task_s = True, t
                case AssistFailed():
                    out.failure = f"assist_failed: {event.phase}: {event.error}"
                case Fault():
                    out.failure = f"fault: {event.error}"
                case _:
                    pass
        stand.events.clear()
    return out


def run_pick_trial(
    evaluator: Evaluator,
    layout: TrialLayout,
    goal: str,
    hesitation: float,
    rng: np.random.Generator,
    on_tick: TickCallback | None = None,
) -> Outcome:
    """One trial of a scene task: the protocol's pick of ``goal`` (``on_tick``: as
    :meth:`Evaluator.pick`'s)."""
    checks = evaluator.prepare(layout.layout)
    if not checks[goal].feasible:
        return Outcome(failure=f"infeasible_grasp: {checks[goal].reason}")
    r = evaluator.pick(goal, rng, onset=hesitation, on_tick=on_tick)
    acted = r.committed or r.confirmed or r.grasped
    out = Outcome(
        chosen=[acted] if acted else [],
        commit_times=[r.commit_time] if r.commit_time is not None else [],
        wrong=int(r.wrong_grasp),
        confirms=int(r.confirmed is not None),
        overrides=r.overrides,
        time_to_grasp_s=r.grasp_time,
        time_to_task_s=r.complete_time,
        effort_s=r.effort,
        completed=r.completed,
        failure="" if r.failure is None else f"{r.failure}: {r.detail}".rstrip(": "),
    )
    return out


def draw_participant(
    population: Population, participants: list[str], pseudonym: str, seed: int
) -> tuple[Participant, np.random.Generator]:
    """``pseudonym`` drawn from ``population`` (the same person for the same seed and place
    in the plan's ``participants``), and the generator of their later draws."""
    rng = np.random.default_rng([seed, 0x57DD, participants.index(pseudonym)])
    return population.draw(pseudonym, rng), rng


def trial_hesitation(
    person: Participant, population: Population, condition: str | None, rng: np.random.Generator
) -> float:
    """The participant's hesitation before a trial's first push, s: their mean, the
    condition's planted shift, the trial's spread (never below 0)."""
    h = population.spec.hesitation
    extra = population.effect(condition).hesitation_s
    return max(0.0, person.hesitation_s + extra + h.trial_sd * float(rng.standard_normal()))


def simulate_participant(
    protocol: Protocol,
    schedule: Schedule,
    population: Population,
    pseudonym: str,
    folder: Path,
    layouts: Layouts,
    *,
    seed: int = 0,
    arm: str = "sawyer",
) -> list[dict[str, Any]]:
    """Run one simulated participant's whole session; write their folder (operator file,
    calibration trace, ``trials.csv``/``.parquet``, ``questionnaires.json``, every trial's
    ``frames/step-NNN.parquet``); returns the trial rows."""
    output_folder(folder)
    index = list(schedule.steps).index(pseudonym)
    person, rng = draw_participant(population, list(schedule.steps), pseudonym, seed)
    params = Params()
    profile = stand_in_profile(params, arm=arm)
    q = protocol.spec.questionnaires
    likert = len(q.likert)
    steps = schedule.steps[pseudonym]
    fitted: OperatorFile | None = None
    if any(s.kind == "calibration" for s in steps):
        fitted = calibrate(
            person, population.spec.calibration_reaches, params, folder, seed + index
        )
    stands: dict[str | None, Any] = {}
    rows: list[dict[str, Any]] = []
    answered: dict[str, dict[str, Any]] = {}
    try:
        for step in steps:
            if step.kind in ("practice", "trial"):
                recorder = FrameRecorder()
                rows.append(
                    _trial(protocol, population, person, fitted, step, layouts, stands,
                           params, profile, rng, recorder)
                )  # fmt: skip
                rows[-1]["frames"] = _write_frames(folder, step.index, recorder, params.dt)
            elif step.kind == "questionnaire" and step.condition is not None:
                answered[step.condition] = answers(
                    person, population, step.condition, likert, q.likert_points, rng
                )
    finally:
        for stand in stands.values():
            stand.close()
    for row in rows:
        row.update(answered.get(row["condition"] or "", {}))
    write_table(folder, "trials", rows, likert)
    write_atomic(
        folder / "questionnaires.json",
        (json.dumps({"participant": pseudonym, "answers": answered}, indent=1) + "\n").encode(),
    )
    return rows


def _write_frames(folder: Path, index: int, recorder: FrameRecorder, dt: float) -> str:
    """The step's frames file in ``folder`` (its path relative to ``folder``); none for a
    trial that did not run (an infeasible grasp: no tick), ``""``."""
    frames = recorder.frames(dt)
    if not len(frames):
        return ""
    relative = frames_path(index)
    output_folder(folder / "frames")
    write_frames(folder / relative, frames)
    return relative


def _trial(
    protocol: Protocol,
    population: Population,
    person: Participant,
    fitted: OperatorFile | None,
    step: Step,
    layouts: Layouts,
    stands: dict[str | None, Any],
    params: Params,
    profile: ProfileSpec,
    rng: np.random.Generator,
    on_tick: TickCallback | None = None,
) -> dict[str, Any]:
    assert step.task is not None and step.layout_seed is not None
    task = protocol.tasks[step.task]
    cond: ConditionSpec | None = (
        protocol.condition(step.condition) if step.condition is not None else None
    )
    assist: AssistPolicy = cond.assist if cond is not None else "commit"
    effect = population.effect(step.condition)
    model = with_effect(person.model, effect.speed_scale)
    hesitation = trial_hesitation(person, population, step.condition, rng)
    layout = layouts.for_trial(task, cond, step.layout_seed, fitted)
    key = step.condition
    if key not in stands:
        base = profile.model_copy(
            update={"control": profile.control.model_copy(update={"assist": assist})}
        )
        operator = fitted.certify_with if fitted is not None else None
        if task.graph is None:
            stands[key] = _EvaluatorStand(
                Evaluator(task.scene, params, base, operator=model, assist=assist)
            )
        else:
            if assist == "none":
                raise InputError(
                    f"condition '{step.condition}': teleoperation alone (assist none) is "
                    "simulated for scene tasks only (the simulated hand grasps, it does not "
                    "place)",
                    field="assist",
                )
            stands[key] = SimStand(base, task.scene, params, graph=task.graph, operator=operator)
    stand = stands[key]
    if isinstance(stand, _EvaluatorStand):
        outcome = run_pick_trial(stand.evaluator, layout, step.targets[0], hesitation, rng, on_tick)
    else:
        outcome = run_graph_trial(
            stand, task, layout, step.targets, model, hesitation, params, rng, on_tick
        )
    certs = trial_certificates(
        task, layout.layout_for, params, fitted.certify_with if fitted is not None else None
    )
    return trial_row(protocol, step, person.pseudonym, assist, layout, certs, outcome,
                     hesitation_s=hesitation)  # fmt: skip


@dataclass
class _EvaluatorStand:
    evaluator: Evaluator

    def close(self) -> None:
        self.evaluator.controller.shutdown()


def simulate_study(
    protocol: Protocol,
    schedule: Schedule,
    population: Population,
    out: Path,
    *,
    seed: int = 0,
    arm: str = "sawyer",
    progress: Any = None,
) -> list[dict[str, Any]]:
    """Every participant of ``schedule``, one after another; ``out/PXX/`` each, and the
    whole study's ``out/trials.csv``/``.parquet`` and data dictionary."""
    output_folder(out)
    layouts = Layouts(out / "layouts", arm=arm)
    rows: list[dict[str, Any]] = []
    for pseudonym in schedule.steps:
        rows += simulate_participant(
            protocol, schedule, population, pseudonym, out / pseudonym, layouts,
            seed=seed, arm=arm,
        )  # fmt: skip
        if progress is not None:
            progress(pseudonym)
    likert = protocol.spec.questionnaires.likert
    write_table(out, "trials", rows, len(likert))
    write_dictionary(out, likert)
    return rows

"""The mode machine: its table forbids what must not happen, and no sequence of joystick
input, operator commands and hardware failures makes the controller take a forbidden
transition (hypothesis, on the real controller and the MuJoCo stand-in)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from legws_daemon.autonomy.modes import (
    STILL,
    TRANSITIONS,
    Activity,
    Gripper,
    Mode,
    ModeMachine,
    SingleCommit,
)
from legws_daemon.errors import LegwsError
from tests.autonomy.rig import Rig, stand_in_profile

A = Activity
ALL = tuple(Activity)

#: Edges that must never be taken, and why (the table's own comments say the same).
_ASSIST_ONLY_AFTER_A_COMMIT = "a goal is assisted only after a commit in teleop"
_RECOVER_ONLY_FROM_FAULT = "only a reset that begins in fault recovers"
FORBIDDEN: dict[tuple[Activity, Activity], str] = {
    **{(a, A.ASSIST): _ASSIST_ONLY_AFTER_A_COMMIT for a in ALL if a not in (A.TELEOP, A.ASSIST)},
    **{(a, A.RECOVER): _RECOVER_ONLY_FROM_FAULT for a in ALL if a not in (A.FAULT, A.RECOVER)},
    (A.FAULT, A.RESET): "a reset in fault is a recovery",
    (A.STOPPED, A.CALIBRATE): "reset a stopped robot first",
    (A.FAULT, A.CALIBRATE): "reset a failed robot first",
    (A.ASSIST, A.CALIBRATE): "the assistance is dropped to teleop first",
    (A.CALIBRATE, A.TELEOP): "a calibration ends in idle (loads are refused during it)",
}


def test_every_activity_has_a_row_and_reports_a_mode() -> None:
    assert set(TRANSITIONS) == set(Activity)
    assert {a.mode for a in Activity} == set(Mode)
    for a, targets in TRANSITIONS.items():
        assert a not in targets  # staying is always allowed, never listed
    assert {a for a in Activity if a.moving} == {A.ASSIST, A.RESET, A.RECOVER}
    assert {a for a in Activity if a.going_home} == {A.RESET, A.RECOVER}
    assert all(a.mode not in STILL for a in Activity if a.moving)


@pytest.mark.parametrize(("edge", "why"), FORBIDDEN.items(), ids=lambda v: str(v))
def test_the_table_forbids_what_must_not_happen(edge: tuple[Activity, Activity], why: str) -> None:
    start, end = edge
    assert end not in TRANSITIONS[start], why
    m = ModeMachine()
    m.state = type(m.state)(activity=start)
    with pytest.raises(AssertionError, match="no transition"):
        m.to(end)
    assert m.activity == start  # refused: nothing changed


def test_stopped_and_fault_move_again_only_through_the_operators_reset() -> None:
    for still in (A.STOPPED, A.FAULT, A.IDLE):
        motions = {a for a in TRANSITIONS[still] if a.moving}
        assert motions == ({A.RECOVER} if still == A.FAULT else {A.RESET})


@st.composite
def machine_calls(draw: st.DrawFn) -> list[tuple[str, Any]]:
    call = st.one_of(
        st.tuples(st.just("to"), st.sampled_from(ALL)),
        st.tuples(st.just("to_fault"), st.sampled_from(["a", "b"])),
        st.tuples(st.just("commit"), st.tuples(st.booleans(), st.booleans())),
        st.tuples(st.just("give_back"), st.none()),
        st.tuples(st.just("gripped"), st.booleans()),
        st.tuples(st.just("single_stage"), st.none()),
        st.tuples(st.just("forget_gripper"), st.none()),
    )
    return draw(st.lists(call, max_size=60))


@given(machine_calls())
def test_the_machine_takes_only_the_tables_edges_and_a_refusal_changes_nothing(
    calls: list[tuple[str, Any]],
) -> None:
    m = ModeMachine()
    for name, arg in calls:
        before = m.state
        try:
            match name:
                case "to":
                    m.to(arg)
                case "to_fault":
                    first = m.to_fault(arg)
                    assert first == (before.activity != A.FAULT)
                    assert m.fault == arg
                case "commit":
                    m.may_commit(single=arg[0], confirmed=arg[1])
                case "give_back":
                    m.give_back()
                    assert m.single == SingleCommit.CONFIRM
                case "gripped":
                    m.gripped(arg)
                    assert m.gripper == Gripper.of(arg)
                case "single_stage":
                    m.single_stage()
                    assert m.single == SingleCommit.AUTO
                case "forget_gripper":
                    m.forget_gripper()
                    assert m.gripper == Gripper.UNKNOWN
        except AssertionError as err:
            if str(err).startswith(("no transition", "a commit in", "a single", "a grip in")):
                assert m.state == before, f"{name}({arg}) refused but changed the state"
                continue
            raise
        a, b = before.activity, m.activity
        assert a == b or b in TRANSITIONS[a], f"{a} -> {b} taken by {name}"
        if name == "commit":
            assert a == A.TELEOP
            assert not (arg[0] and not arg[1]) or before.single == SingleCommit.AUTO
        if name == "gripped":
            assert a.moving
        assert (m.fault is not None) == (b == A.FAULT)


# --- the real controller -----------------------------------------------------------------

#: What a step does: ticks of joystick input, an operator command or a hardware change.
STEPS = (
    "toward", "toward", "toward", "hands_off", "deadman", "confirm", "cancel", "push_away",
    "stop", "reset", "calibrate", "load", "fail", "heal", "grip_fail", "grip_heal",
    "gripper_button",
)  # fmt: skip


@dataclass
class Recorder:
    """Every edge the controller's machine took (``to`` wrapped)."""

    edges: list[tuple[Activity, Activity]]


def _record(rig: Rig) -> Recorder:
    machine = rig.c.modes
    taken = Recorder([])
    to = machine.to

    def recorded(activity: Activity) -> None:
        before = machine.activity
        to(activity)  # raises on a forbidden edge: the property fails with its message
        if activity != before:
            taken.edges.append((before, activity))

    machine.to = recorded  # type: ignore[method-assign]
    return taken


def _unit(v: np.ndarray) -> list[float]:
    return [float(x) for x in v / max(float(np.linalg.norm(v)), 1e-9)]


def _ticks(rig: Rig, step: str, n: int) -> None:
    c = rig.c
    for _ in range(n):
        before = c.mode
        grips = len(rig.adapter.grips)
        targets = c.stage.targets if c.mode == Mode.TELEOP else ()
        match step:
            case "toward" if targets and c.last_state is not None:
                goal = targets[rig.seq % len(targets)]
                inp = rig.sample(_unit(goal.position - c.last_state.ee_position))
            case "push_away" if c.committed is not None and c.last_state is not None:
                # the stick held against the committed goal (a cancel by direction)
                goal = next((t for t in c.stage.targets if t.name == c.committed), None)
                away = c.last_state.ee_position - (goal.position if goal else np.zeros(3))
                inp = rig.sample(_unit(away))
            case "confirm":
                inp = rig.sample([0.0, 0.0, 0.0], confirm=True)
            case "cancel":
                inp = rig.sample([0.0, 0.0, 0.0], cancel=True)
            case "gripper_button":  # the operator's gripper button: closed, then open
                inp = rig.sample([0.0, 0.0, 0.0], gripper=rig.seq % 2 == 0)
            case "deadman":
                inp = None
            case _:
                inp = rig.hands_off()
        record = c.tick(inp)
        # a tick alone never leaves stopped, fault or idle for a mode that moves (only the
        # operator's reset or a load does); it may fail, or hear the robot side's stop
        if before in STILL:
            assert c.mode in STILL, f"a tick left {before} for {c.mode}"
        # nothing moves in idle, stopped and fault
        if record.mode in STILL:
            assert not np.any(record.command), record
            assert record.joints is None or not np.any(record.joints)
        # only a plan grips, or the operator's gripper button in teleoperation
        if len(rig.adapter.grips) > grips:
            assert before == Mode.ASSIST or (before == Mode.TELEOP and step == "gripper_button")


def _command(rig: Rig, step: str) -> None:
    c = rig.c
    before = c.modes.state
    try:
        match step:
            case "stop":
                rig.command("stop")
                assert c.mode == Mode.STOPPED
                return
            case "reset":
                rig.command("reset")
                assert c.modes.activity == (A.RECOVER if before.activity == A.FAULT else A.RESET)
                return
            case "calibrate":
                c.start_calibration(3, 0)
                assert c.mode == Mode.CALIBRATE
                return
            case "load":
                rig.command("load_taskgraph", "tea")
                assert c.mode in (Mode.TELEOP, Mode.ASSIST, Mode.IDLE)
                return
    except LegwsError:
        # refused: the mode is where it was (a refused load or calibration moves nothing)
        assert c.modes.activity == before.activity


@pytest.fixture(scope="module")
def profile() -> Any:
    return stand_in_profile()


#: Examples per run (LEGWS_MODE_EXAMPLES for a longer search). No shrinking: each failing
#: example's traceback keeps its controller and MuJoCo model, and a shrink tries hundreds.
EXAMPLES = int(os.environ.get("LEGWS_MODE_EXAMPLES", "16"))


@settings(
    max_examples=EXAMPLES, deadline=None, derandomize=True,
    phases=[Phase.explicit, Phase.generate],
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)  # fmt: skip
@given(st.lists(st.tuples(st.sampled_from(STEPS), st.integers(1, 40)), min_size=4, max_size=18))
def test_no_sequence_of_input_commands_and_failures_takes_a_forbidden_transition(
    profile: Any, steps: list[tuple[str, int]]
) -> None:
    rig = Rig.of(profile, "tea")
    taken = _record(rig)
    for step, n in steps:
        match step:
            case "fail" | "heal":
                rig.adapter.failing = step == "fail"
            case "grip_fail" | "grip_heal":
                rig.adapter.grip_failing = step == "grip_fail"
            case "stop" | "reset" | "calibrate" | "load":
                _command(rig, step)
            case _:
                _ticks(rig, step, n)
    for a, b in taken.edges:
        assert b in TRANSITIONS[a] and (a, b) not in FORBIDDEN, (a, b)

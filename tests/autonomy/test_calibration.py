"""Mode ``calibrate`` (``legws operator calibrate``) on the controller in process: one target
at a time, each reach recorded as the controller saw it, the dead-man and the stop as in
teleoperation, the reset going on with the interrupted target, loads refused."""

from __future__ import annotations

import numpy as np
import pytest

from legws_daemon.autonomy.calibration import CALIBRATION, calibration_box, targets_for
from legws_daemon.autonomy.events import CalibrationReach, CalibrationReached, Commit, Reset
from legws_daemon.core.calibration import ARRIVED, MIN_REACH
from legws_daemon.core.operator import OperatorModel
from legws_daemon.errors import InputError
from legws_daemon.formats.log_lines import parse_reach
from legws_daemon.formats.messages import CommandRequest
from legws_daemon.joystick.sim_user import CALIBRATION_TARGET, SimUser
from legws_daemon.safety.envelope import Box
from legws_daemon.scene.catalog import load_scene
from tests.autonomy.operators import Bench
from tests.autonomy.rig import LOADERS, operator_command

OPERATOR = OperatorModel(1.0, 0.03, 0.6, 10.0, "free")


def user(seed: int = 0, operator: OperatorModel | None = OPERATOR) -> SimUser:
    return SimUser([], 0.03, 0.05, np.random.default_rng(seed), operator=operator)


def test_targets_lie_above_the_table_clear_of_the_objects_and_far_enough_apart() -> None:
    scene = load_scene("desk")
    box = Box(np.array([0.2, -0.55, 0.0]), np.array([0.95, 0.55, 0.6]))
    cal = calibration_box(scene, box)
    tallest = max(o.size[-1] for o in scene.objects.values())
    assert cal.low[2] >= scene.workspace.table_height + tallest
    assert cal.high[2] <= scene.home.position[2] + 0.1 + 1e-9
    start = scene.home.position
    targets = targets_for(scene, box, start, 20, seed=3)
    again = targets_for(scene, box, start, 20, seed=3)
    np.testing.assert_array_equal(np.array(targets), np.array(again))  # seeded
    assert np.all(np.round(np.array(targets), 4) == np.array(targets))  # as the log line says
    here = start
    for t in targets:
        assert np.all(t >= cal.low - 1e-4) and np.all(t <= cal.high + 1e-4)
        assert np.linalg.norm(t - here) >= MIN_REACH - 1e-3
        here = t
    with pytest.raises(InputError, match="targets"):
        targets_for(scene, box, start, 1, seed=0)


def test_a_calibration_shows_each_target_records_each_reach_and_ends_idle() -> None:
    b = Bench()
    run = b.calibrate(user(), 3, seed=1)
    assert b.c.mode == "idle"
    assert run.finished and len(run.done) == 3
    kinds = [e for e in b.events if isinstance(e, CalibrationReach | CalibrationReached)]
    assert [(type(e).__name__, e.reach) for e in kinds] == [
        ("CalibrationReach", 1), ("CalibrationReached", 1),
        ("CalibrationReach", 2), ("CalibrationReached", 2),
        ("CalibrationReach", 3), ("CalibrationReached", 3),
    ]  # fmt: skip
    assert not any(isinstance(e, Commit) for e in b.events)  # no inference, no assistance
    for e in kinds:  # the lines legws operator trace reads back
        line = parse_reach(e.text())
        assert line is not None and line.reach == e.reach
        if isinstance(e, CalibrationReach):
            assert line.target == pytest.approx(run.targets[e.reach - 1])
            assert line.of == 3
    for reach, done in zip(run.done, [e for e in kinds if isinstance(e, CalibrationReached)],
                           strict=True):  # fmt: skip
        assert reach.ee.shape == reach.u.shape and len(reach.ee) == done.ticks
        assert reach.seconds == pytest.approx(done.ticks * b.c.dt)
        assert np.linalg.norm(reach.ee[-1] - reach.target) < 0.05  # it got there ...
        assert np.all(np.linalg.norm(reach.ee - reach.target, axis=1) >= ARRIVED)  # ... last
        assert np.all(np.linalg.norm(reach.u, axis=1) <= 1 + 1e-9)
    # the status of the target shown, and none after the last
    assert run.status(b.adapter.kinematics.ee_position()) is None


def test_the_recorded_deflection_is_the_one_used_and_zero_without_input() -> None:
    b = Bench()
    run = b.c.start_calibration(2, seed=0)
    b.tick(None, {})  # the first target appears; no input: nothing moves
    start = b.adapter.kinematics.ee_position()
    for _ in range(10):
        b.tick(None, {})
    assert np.linalg.norm(b.adapter.kinematics.ee_position() - start) < 1e-3
    u = user(operator=None)
    used = []
    for _ in range(20):
        target = run.target
        assert target is not None
        rec = b.tick(u, {CALIBRATION_TARGET: target})
        assert rec.joystick is not None
        used.append(rec.joystick)
    assert run._u[:11] == [pytest.approx(np.zeros(3))] * 11  # the ticks without input
    np.testing.assert_allclose(np.array(run._u[11:]), np.array(used))
    moved = b.adapter.kinematics.ee_position() - start
    assert np.dot(moved, run.targets[0] - start) > 0  # toward the target


def test_confirm_and_cancel_do_nothing_while_calibrating() -> None:
    b = Bench()
    run = b.c.start_calibration(2, seed=0)
    for _ in range(5):
        target = run.targets[0]
        d = target - b.adapter.kinematics.ee_position()
        from legws_daemon.autonomy.inputs import OperatorInput

        b.c.tick(OperatorInput(d / np.linalg.norm(d), confirm=True, cancel=True))
        b.clock.advance()
    assert b.c.mode == "calibrate" and b.c.committed is None
    assert not any(isinstance(e, Commit) for e in b.events)


def test_a_stop_drops_the_reach_under_way_and_a_reset_shows_its_target_again() -> None:
    b = Bench()
    run = b.c.start_calibration(3, seed=2)
    u = user(seed=4)
    while not run.done:
        b.tick(u, {} if run.target is None else {CALIBRATION_TARGET: run.target})
    for _ in range(30):  # half-way through reach 2
        b.tick(u, {CALIBRATION_TARGET: run.target} if run.target is not None else {})
    assert run.index == 1 and len(run._ee) > 0
    b.c.stop("operator")
    assert b.c.mode == "stopped" and run._ee == [] and run.target is None
    for _ in range(5):
        rec = b.tick(u, {})
        assert np.allclose(rec.command, 0.0)  # stopped: nothing moves
    operator_command(b.c, CommandRequest.model_validate({"schema": 1, "command": "reset"}))
    assert b.c.mode == "assist"
    for _ in range(2000):  # the way home (the user holds the dead-man, hands off)
        if b.c.mode != "assist":
            break
        b.tick(u, {})
    assert b.c.mode == "calibrate"
    assert any(isinstance(e, Reset) for e in b.events)
    b.tick(u, {})
    shown = [e.reach for e in b.events if isinstance(e, CalibrationReach)]
    assert shown == [1, 2, 2]  # reach 2 again, from home
    assert len(run.done) == 1


def test_loads_are_refused_until_the_calibration_ends() -> None:
    b = Bench()
    b.c.start_calibration(2, seed=0)
    load = CommandRequest.model_validate({"schema": 1, "command": "load_scene", "argument": "desk"})
    with pytest.raises(InputError, match="calibration"):
        b.c.prepare(load, *LOADERS)
    assert b.c.mode == "calibrate"
    assert CALIBRATION == CALIBRATION_TARGET  # status stage and target name agree

"""The daemon's status and events for a person (``--operator``) and during a calibration,
from the service in this process (no zenoh session: the status is built and validated as
the loop builds it)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from legws_daemon.autonomy.controller import Controller
from legws_daemon.autonomy.events import Commit
from legws_daemon.cli.daemon import operator_for
from legws_daemon.core.certificate import certify
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.daemon.service import CalibrationSpec, DaemonConfig, DaemonService
from legws_daemon.formats.messages import StatusMessage, dump, parse
from legws_daemon.formats.operator_file import OperatorFile, load_operator
from legws_daemon.formats.profile import load_profile
from legws_daemon.scene.catalog import load_scene
from legws_daemon.transport.session import config_from_spec
from tests.daemon.procs import write_profile
from tests.net import free_port

ALICE = OperatorFile(
    "alice",
    OperatorModel(0.92, 0.031, 0.83, -4.1, "free"),
    OperatorModel(0.90, 0.033, 0.86, -6.0, "free"),
    {"speed": (0.90, 0.94), "sigma": (0.029, 0.033), "rho": (0.80, 0.86),
     "bias_deg": (-6.0, -2.2)},
    20, 3120, source="/people/alice.json",
)  # fmt: skip


def service(
    tmp_path: Path, operator: OperatorFile | None, calibration: CalibrationSpec | None = None
) -> DaemonService:
    """A service with its controller built as its loop builds it (no session, no loop)."""
    profile = load_profile(write_profile(tmp_path, "sim", free_port()))
    scene = load_scene("desk")
    params = Params(v_max=profile.control.v_max, dt=1.0 / profile.control.rate_hz)
    config = DaemonConfig(
        profile, scene, scene.default_layout(), params, config_from_spec(profile.transport),
        operator=operator, calibration=calibration,
    )  # fmt: skip
    s = DaemonService(config)
    s.controller = Controller(
        profile, scene, scene.default_layout(), s.make_adapter, params, s._from_controller,
        operator=operator.certify_with if operator is not None else None,
    )  # fmt: skip
    if calibration is not None:
        s.controller.start_calibration(calibration.targets, calibration.seed)
    return s


def status(s: DaemonService) -> StatusMessage:
    """The status as it goes on the wire, read back as a client reads it."""
    assert s.controller is not None
    rec = s.controller.tick(None)
    return parse(StatusMessage, dump(s._status(rec, s.controller.live_slack())), "status")


def test_status_names_the_operator_and_its_certificate_is_theirs(tmp_path: Path) -> None:
    s = service(tmp_path, ALICE)
    try:
        msg = status(s)
        assert msg.operator is None  # the lease holder: nobody yet (a field of its own)
        model = msg.operator_model
        assert model is not None and model.name == "alice"
        assert model.model.rho == 0.86 and model.model.bias_deg == -6.0
        assert model.intervals["rho"] == (0.80, 0.86)
        assert model.file == "/people/alice.json"
        assert model.watch is not None and model.watch.window == 10
        assert model.watch.estimate is None and model.watch.warning is None
        assert s.controller is not None
        goals = s.controller.stage.goals_home
        assert goals is not None
        params = s.config.params
        op = ALICE.certify_with
        assert msg.certificate == certify(goals, params, op, op.motion(params, clip=True)).objective
        assert msg.certificate != pytest.approx(certify(goals, params).objective, abs=0.05)
        assert msg.calibration is None
    finally:
        assert s.controller is not None
        s.controller.shutdown()


def test_without_an_operator_status_has_none_and_no_watch_runs(tmp_path: Path) -> None:
    s = service(tmp_path, None)
    try:
        msg = status(s)
        assert msg.operator_model is None and s.watch is None
        assert s.controller is not None and s.controller.stage.goals_home is not None
        params = s.config.params
        assert msg.certificate == certify(s.controller.stage.goals_home, params).objective
    finally:
        assert s.controller is not None
        s.controller.shutdown()


def test_the_watch_sees_a_commit_with_its_goals_position(tmp_path: Path) -> None:
    s = service(tmp_path, ALICE)
    try:
        c, watch = s.controller, s.watch
        assert c is not None and watch is not None
        goal = c.stage.targets[0]
        s._from_controller(
            Commit(goal.name, 0.95, 1, 1.0, 0.0, c.stage.name, c.stage.name, "pick", False,
                   False, c.stage.certificate)
        )  # fmt: skip
        pending = watch.segments._pending
        assert pending is not None and pending[0] == goal.name
        np.testing.assert_allclose(pending[1][2], goal.position)
    finally:
        assert s.controller is not None
        s.controller.shutdown()


def test_status_during_a_calibration(tmp_path: Path) -> None:
    s = service(tmp_path, None, CalibrationSpec(4, seed=2))
    try:
        msg = status(s)  # the first tick shows the first target
        assert msg.mode == "calibrate" and msg.stage == "calibration"
        assert msg.certificate is None and msg.posterior == {} and msg.committed is None
        assert msg.calibration is not None
        assert (msg.calibration.reach, msg.calibration.of) == (1, 4)
        assert set(msg.targets) == {"calibration"}
        assert msg.targets["calibration"] == msg.calibration.target
        assert msg.ee is not None
        here = np.array(msg.ee.position)
        distance = np.linalg.norm(np.array(msg.calibration.target) - here)
        assert msg.calibration.distance == pytest.approx(distance, abs=1e-4)
        assert s.watch is None  # nothing to watch while calibrating
    finally:
        assert s.controller is not None
        s.controller.shutdown()


def test_operator_comes_from_the_option_else_the_profile(tmp_path: Path) -> None:
    path = tmp_path / "alice.json"
    ALICE.write(path)
    bob = tmp_path / "bob.json"
    bob.write_text(json.dumps({**json.loads(path.read_text()), "name": "bob"}))
    text = tmp_path / "p.toml"
    base = write_profile(tmp_path, "sim", free_port()).read_text()
    text.write_text(base.replace("[control]\n", '[control]\noperator = "bob.json"\n', 1))
    spec = load_profile(text)
    chosen = operator_for(spec, path)
    assert chosen is not None and chosen.name == "alice"
    chosen = operator_for(spec, None)
    assert chosen is not None and chosen.name == "bob"
    assert operator_for(load_profile(write_profile(tmp_path, "sim", free_port())), None) is None
    assert load_operator(path).certify_with == ALICE.certify_with

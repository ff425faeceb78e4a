"""One read per tick: the tick reads the robot state once and hands it to the command's
envelope, the assistance and telemetry; no second MuJoCo model is built to draw the arm.
On the stand-in through a whole pick, and on the real arm's adapter through the fake bridge
over loopback zenoh (one bridge-state read and one forward-kinematics evaluation per tick
of teleoperation)."""

from __future__ import annotations

import time
from collections import Counter
from typing import Any

import numpy as np
import pytest

from legws_daemon.autonomy.controller import Controller
from legws_daemon.autonomy.inputs import OperatorInput
from legws_daemon.autonomy.modes import Mode
from legws_daemon.core.params import Params
from legws_daemon.formats.profile import load_profile
from legws_daemon.hardware.base import RobotState
from legws_daemon.hardware.bridge import BridgeAdapter
from legws_daemon.hardware.fake_bridge import FakeBridge
from legws_daemon.robot import world as world_module
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from tests.autonomy.rig import PROFILE, Rig, StandIn, stand_in_profile
from tests.hardware.helpers import peers


class CountingStandIn(StandIn):
    reads = 0

    def _read_state(self) -> RobotState:
        self.reads += 1
        return super()._read_state()


@pytest.fixture
def worlds_built(monkeypatch: pytest.MonkeyPatch) -> Counter[str]:
    """Counts every MuJoCo model compiled (``World`` built) while the test runs."""
    built: Counter[str] = Counter()
    real = world_module.World.__init__

    def init(self: world_module.World, *args: Any, **kwargs: Any) -> None:
        built["world"] += 1
        real(self, *args, **kwargs)

    monkeypatch.setattr(world_module.World, "__init__", init)
    return built


def test_the_stand_in_is_read_once_per_tick_through_a_whole_pick(
    worlds_built: Counter[str],
) -> None:
    rig = Rig(stand_in_profile(), load_scene("desk"))
    a = CountingStandIn(rig.profile, rig.c.scene)
    a.connect()
    rig.c.adapter = a  # the counting stand-in drives the robot from here on
    rig.c.restart_task()
    built = worlds_built["world"]
    phases: set[str] = set()
    kinds = set()
    for _ in range(3000):
        # the user looks at the robot (a read of its own), then the tick
        inp = rig.toward("white_mug") if rig.c.mode == Mode.TELEOP else rig.hands_off()
        before = a.reads
        rec = rig.c.tick(inp)
        assert a.reads - before == 1, (rec.mode, rec.phase)
        if rec.phase:
            phases.add(rec.phase)
        kinds.add("joints" if rec.joints is not None else "cartesian")
        assert rec.state is not None and rec.state.links.positions.shape[1] == 3
        if rig.c.mode == Mode.IDLE:
            break
    assert rig.c.mode == Mode.IDLE
    assert {"carry", "reach", "grasp", "lift", "home"} <= phases
    assert kinds == {"joints", "cartesian"}
    assert worlds_built["world"] == built  # nothing compiled while ticking


@pytest.mark.slow
def test_the_real_arm_is_read_once_per_tick_through_the_fake_bridge(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The sawyer adapter against the fake bridge: each tick of teleoperation is one
    bridge-state read and one forward-kinematics evaluation of the adapter's model."""
    scene = load_scene("desk")
    profile = load_profile(PROFILE.parent / "sawyer.toml")
    reads: Counter[str] = Counter()
    models: list[world_module.World] = []
    real_set_q = world_module.World.set_q
    real_fresh = BridgeAdapter._fresh

    def set_q(self: world_module.World, q: Any) -> None:
        if any(self is m for m in models):
            reads["fk"] += 1
        real_set_q(self, q)

    def fresh(self: BridgeAdapter) -> Any:
        reads["bridge"] += 1
        return real_fresh(self)

    monkeypatch.setattr(world_module.World, "set_q", set_q)
    monkeypatch.setattr(BridgeAdapter, "_fresh", fresh)
    with peers() as (daemon, robot), FakeBridge(robot, "sawyer", scene, rate_hz=200.0):

        def make(sc: Scene) -> BridgeAdapter:
            adapter = BridgeAdapter(profile, sc, daemon)
            adapter.connect()
            models.append(adapter.kinematics)
            return adapter

        c = Controller(profile, scene, scene.default_layout(), make, Params(), lambda e: None)
        try:
            for _ in range(20):
                inp = _toward(c, "black_stapler")
                reads.clear()
                c.tick(inp)
                assert c.mode == Mode.TELEOP
                assert reads == Counter({"bridge": 1, "fk": 1}), reads
                time.sleep(c.dt)
        finally:
            c.shutdown()


def _toward(c: Controller, goal: str) -> OperatorInput:
    state = c.last_state if c.last_state is not None else c.adapter.read_state()
    d = c.stage.target(goal).position - state.ee_position
    return OperatorInput(d / max(float(np.linalg.norm(d)), 1e-9), received=time.monotonic())

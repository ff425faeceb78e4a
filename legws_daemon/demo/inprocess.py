"""A demo without processes or wall clock: the controller and the simulated user tick by
tick in one process, as fast as the stand-in computes. For tests and benchmarks (many seeds);
``legws demo`` runs the real daemon."""

from __future__ import annotations

from typing import Any

import numpy as np

from legws_daemon.autonomy.controller import Controller
from legws_daemon.autonomy.events import Event
from legws_daemon.autonomy.inputs import OperatorInput
from legws_daemon.autonomy.modes import Mode
from legws_daemon.core.params import Params
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.joystick.sim_user import SimUser, UserView
from legws_daemon.scene.scene import Scene
from legws_daemon.sim.protocol import SimClock
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import Plan

#: A run that has not finished after this many ticks (15 simulated minutes) is stopped.
TICK_LIMIT = 18_000


def user_view(c: Controller) -> UserView:
    """What the daemon's status would show the user (the fields it reads)."""
    s = c.adapter.read_state()
    targets = {t.name: t.position for t in c.stage.targets}
    return UserView(c.mode.value, c.decisions, c.stage.name, s.ee_position, targets)


def run_inprocess(
    profile: ProfileSpec,
    graph: TaskGraph,
    scene: Scene,
    seed: int,
    *,
    plan: Plan | None = None,
    params: Params | None = None,
    limit: int = TICK_LIMIT,
) -> tuple[Controller, list[dict[str, Any]], SimUser]:
    """Run ``graph`` with the simulated user choosing at random (seeded); returns the
    controller (its final state), the events (as on the wire) and the user (its choices)."""
    stand_in = profile.model_copy(
        update={"sim": profile.sim.model_copy(update={"realtime": False})}
    )
    events: list[dict[str, Any]] = []
    clock = SimClock(1.0 / profile.control.rate_hz)

    def make(sc: Scene) -> SimAdapter:
        a = SimAdapter(stand_in, sc, clock=clock)
        a.connect()
        return a

    def emit(event: Event) -> None:
        events.append({"kind": event.kind, "detail": event.detail()})

    c = Controller(
        stand_in, scene, scene.default_layout(), make,
        params or Params(v_max=profile.control.v_max, dt=1.0 / profile.control.rate_hz),
        emit, graph=graph, plan=plan, clock=clock,
    )  # fmt: skip
    user = SimUser([], Params().sigma, profile.control.v_max, np.random.default_rng(seed))
    try:
        for tick in range(1, limit):
            if c.mode in (Mode.IDLE, Mode.FAULT):
                break
            act = user.act(user_view(c), clock())
            c.tick(OperatorInput(act.axes, act.confirm, act.cancel, clock(), tick))
            clock.advance()
    finally:
        c.shutdown()
    return c, events, user

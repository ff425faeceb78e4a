"""A demo without processes or wall clock: the controller and the simulated user tick by
tick in one process, as fast as the stand-in computes. For tests and benchmarks (many seeds);
``legws demo`` runs the real daemon."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from legws_daemon.core.params import Params
from legws_daemon.daemon.controller import Controller
from legws_daemon.daemon.inbox import JoystickInbox
from legws_daemon.formats.messages import StatusMessage
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.joystick.sim_user import SimUser
from legws_daemon.scene.scene import Scene
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import Plan

#: A run that has not finished after this many ticks (15 simulated minutes) is stopped.
TICK_LIMIT = 18_000


def status_of(c: Controller) -> StatusMessage:
    """What the daemon would publish (the fields the simulated user reads)."""
    s = c.adapter.read_state()
    return StatusMessage.model_validate(
        {"schema": 1, "robot": "sim", "seq": c.ticks, "stamp": 0.0, "mode": c.mode,
         "stage": c.stage.name, "adapter": "sim", "decision": c.decisions,
         "ee": {"position": s.ee_position.tolist(), "quaternion": s.ee_quaternion.tolist()},
         "targets": {t.name: t.position.tolist() for t in c.stage.targets}},
    )  # fmt: skip


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
    controller (its final state), the events and the user (its choices)."""
    stand_in = profile.model_copy(
        update={"sim": profile.sim.model_copy(update={"realtime": False})}
    )
    events: list[dict[str, Any]] = []

    def make(sc: Scene) -> SimAdapter:
        a = SimAdapter(stand_in, sc)
        a.connect()
        return a

    c = Controller(
        stand_in, scene, scene.default_layout(), make,
        params or Params(v_max=profile.control.v_max, dt=1.0 / profile.control.rate_hz),
        lambda k, d: events.append({"kind": k, "detail": d}), graph=graph, plan=plan,
    )  # fmt: skip
    user = SimUser([], Params().sigma, profile.control.v_max, np.random.default_rng(seed))
    inbox = JoystickInbox()
    try:
        for tick in range(1, limit):
            if c.mode in ("idle", "fault"):
                break
            out = user.sample(status_of(c), tick * c.dt)
            if out is None:
                raise RuntimeError("the simulated user got no status")
            axes, buttons = out
            msg = {"schema": 1, "seq": tick, "stamp": 0.0, "axes": list(axes),
                   "buttons": buttons.model_dump()}  # fmt: skip
            c.tick(inbox.offer(json.dumps(msg).encode(), float(tick)))
    finally:
        c.shutdown()
    return c, events, user

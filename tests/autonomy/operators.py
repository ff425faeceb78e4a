"""Simulated operators (method.md §10) on the controller in process: calibration runs and
picks on the unpaced stand-in in simulated time, the simulated user steering as
``legws joystick sim-user --rho … --bias …`` does (the same :class:`SimUser`)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from legws_daemon.autonomy.calibration import CalibrationRun
from legws_daemon.autonomy.controller import Controller
from legws_daemon.autonomy.events import Event
from legws_daemon.autonomy.inputs import OperatorInput, TickRecord
from legws_daemon.autonomy.modes import Mode
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.joystick.sim_user import CALIBRATION_TARGET, SimUser, UserView
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from legws_daemon.sim.protocol import SimClock, stand_in_profile

#: A pick that has not ended after this many ticks is a test failure (100 s simulated).
PICK_LIMIT = 2000


class Bench:
    """A controller on the unpaced stand-in in simulated time, with every event kept and
    passed to ``on_event`` hooks (with the committed goal's position for a commit), and
    every tick record to ``on_tick`` hooks."""

    def __init__(
        self,
        scene: str = "desk",
        operator: OperatorModel | None = None,
        params: Params | None = None,
    ) -> None:
        self.params = params or Params()
        self.scene: Scene = load_scene(scene)
        self.profile = stand_in_profile(self.params)
        self.clock = SimClock(self.params.dt)
        self.events: list[Event] = []
        self.on_event: list[Callable[[Event, np.ndarray | None], None]] = []
        self.on_tick: list[Callable[[TickRecord], None]] = []
        self._adapter: SimAdapter | None = None

        def make(sc: Scene) -> SimAdapter:
            a = SimAdapter(self.profile, sc, clock=self.clock)
            a.connect()
            self._adapter = a
            return a

        self.c = Controller(
            self.profile, self.scene, self.scene.default_layout(), make, self.params,
            self._emit, clock=self.clock, operator=operator,
        )  # fmt: skip

    def _emit(self, event: Event) -> None:
        self.events.append(event)
        position = None
        goal = getattr(event, "goal", None)
        if event.kind == "commit" and goal is not None:
            position = self.c.stage.target(goal).position
        for hook in self.on_event:
            hook(event, position)

    @property
    def adapter(self) -> SimAdapter:
        assert self._adapter is not None
        return self._adapter

    def view(self, targets: dict[str, np.ndarray]) -> UserView:
        here = self.adapter.kinematics.ee_position()
        return UserView(self.c.mode.value, self.c.decisions, self.c.stage.name, here, targets)

    def tick(self, user: SimUser | None, targets: dict[str, np.ndarray]) -> TickRecord:
        """One control period with the user's action (``None``: no input at all)."""
        inp = None
        if user is not None:
            act = user.act(self.view(targets), self.clock())
            inp = OperatorInput(act.axes, act.confirm, act.cancel, self.clock())
        rec = self.c.tick(inp)
        self.clock.advance()
        for hook in self.on_tick:
            hook(rec)
        return rec

    def calibrate(self, user: SimUser, count: int, seed: int = 0) -> CalibrationRun:
        """A whole calibration of ``count`` targets, steered by ``user``."""
        run = self.c.start_calibration(count, seed)
        for _ in range(PICK_LIMIT * count):
            if self.c.mode == Mode.IDLE:
                return run
            target = run.target
            self.tick(user, {CALIBRATION_TARGET: target} if target is not None else {})
        raise AssertionError("the calibration did not end")

    def pick(self, goal: str, operator: OperatorModel | None, rng: np.random.Generator) -> None:
        """One pick of ``goal`` from home (the arm reset there, the task restarted), until
        the task is done."""
        self.adapter.reset_arm()
        self.c.restart_task()
        sigma = operator.sigma if operator is not None else self.params.sigma
        user = SimUser([goal], sigma, self.params.v_max, rng, operator=operator)
        for _ in range(PICK_LIMIT):
            if self.c.mode == Mode.IDLE:
                return
            targets = {t.name: t.position for t in self.c.stage.targets}
            self.tick(user, targets)
        raise AssertionError(f"the pick of {goal} did not end")

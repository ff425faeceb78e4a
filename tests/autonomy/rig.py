"""A controller on the real MuJoCo stand-in, a joystick and the events: the rig of the
autonomy tests. The joystick goes through the daemon's inbox (validation included); the
stand-in has fault switches at the hardware edge."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, assert_never

import numpy as np

from legws_daemon.autonomy.controller import Controller
from legws_daemon.autonomy.events import Event
from legws_daemon.autonomy.inputs import OperatorInput
from legws_daemon.autonomy.modes import Mode
from legws_daemon.core.params import Params
from legws_daemon.daemon.inbox import JoystickInbox
from legws_daemon.daemon.service import catalog_scene, catalog_taskgraph
from legws_daemon.errors import HardwareError, InputError
from legws_daemon.formats.messages import CommandRequest
from legws_daemon.formats.profile import ProfileSpec, load_profile
from legws_daemon.hardware.base import RobotState
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.safety.envelope import Box
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene
from legws_daemon.task.graph import TaskGraph

PROFILE = Path(__file__).parents[2] / "hw_profiles" / "sim.toml"
LOADERS = (catalog_scene, catalog_taskgraph)


def stand_in_profile(rate_hz: float | None = None) -> ProfileSpec:
    """The sim profile, unpaced (and at another control rate if asked)."""
    p = load_profile(PROFILE)
    p = p.model_copy(update={"sim": p.sim.model_copy(update={"realtime": False})})
    if rate_hz is not None:
        p = p.model_copy(update={"control": p.control.model_copy(update={"rate_hz": rate_hz})})
    return p


class StandIn(SimAdapter):
    """The stand-in with switches that make the hardware fail (the hardware edge):
    ``failing`` (every call raises), ``wrist_jammed`` (orientation holds are ignored: the
    arm keeps the orientation it has), ``joints_jammed`` (joint-space commands move
    nothing), ``grip_failing`` (the gripper refuses). ``grips`` records every grip the
    gripper carried out (``True``: close)."""

    failing = False
    wrist_jammed = False
    joints_jammed = False
    grip_failing = False

    def __init__(self, profile: ProfileSpec, scene: Scene) -> None:
        super().__init__(profile, scene)
        self.grips: list[bool] = []

    def _grip(self, closed: bool) -> None:
        if self.grip_failing:
            raise HardwareError("gripper not responding")
        super()._grip(closed)
        self.grips.append(closed)

    def _read_state(self) -> RobotState:
        if self.failing:
            raise HardwareError("bridge heartbeat lost")
        return super()._read_state()

    def _command(
        self, state: RobotState, velocity: np.ndarray, hold: np.ndarray | None, box: Box
    ) -> None:
        if self.failing:
            raise HardwareError("command refused")
        super()._command(state, velocity, None if self.wrist_jammed else hold, box)

    def _command_joints(self, state: RobotState, qdot: np.ndarray) -> None:
        if self.failing:
            raise HardwareError("command refused")
        super()._command_joints(state, np.zeros(7) if self.joints_jammed else qdot)


class Rig:
    """A controller on :class:`StandIn` running a task graph (or a scene's pick)."""

    def __init__(self, profile: ProfileSpec, scene: Scene, graph: TaskGraph | None = None) -> None:
        self.profile = profile
        self.typed: list[Event] = []
        self.events: list[tuple[str, dict[str, Any]]] = []
        self.inbox = JoystickInbox()
        self.inbox.take_control("rig", 0.0)  # the rig's session is the operator throughout
        self.seq = 0
        #: called with every event after it is recorded
        self.on_event: list[Callable[[Event], None]] = []

        def make(sc: Scene) -> StandIn:
            a = StandIn(profile, sc)
            a.connect()
            return a

        def emit(event: Event) -> None:
            self.typed.append(event)
            self.events.append((event.kind, event.detail()))
            for hook in self.on_event:
                hook(event)

        self.c = Controller(
            profile, scene, scene.default_layout(), make,
            Params(v_max=profile.control.v_max, dt=1 / profile.control.rate_hz), emit,
            graph=graph,
        )  # fmt: skip

    @classmethod
    def of(cls, profile: ProfileSpec, name: str) -> Rig:
        """``desk`` (or another scene): its pick; else the task graph ``name``."""
        if name in ("desk", "breakfast_easy", "breakfast", "kitchen_prep", "meal_assembly"):
            return cls(profile, load_scene(name))
        graph, scene = catalog_taskgraph(name)
        return cls(profile, scene, graph)

    @property
    def adapter(self) -> StandIn:
        a = self.c.adapter
        assert isinstance(a, StandIn)
        return a

    def sample(self, axes: Any, rotation: Any = None, **buttons: bool | None) -> OperatorInput:
        """A joystick message through the daemon's inbox, as the controller gets it."""
        self.seq += 1
        msg: dict[str, Any] = {"schema": 1, "seq": self.seq, "stamp": 0.0,
                               "axes": [float(a) for a in axes], "source": "t",
                               "session": "rig"}  # fmt: skip
        if buttons:
            msg["buttons"] = buttons
        if rotation is not None:
            msg["rotation"] = [float(a) for a in rotation]
        now = self.c.dt * self.seq
        assert self.inbox.offer(json.dumps(msg).encode(), now) is not None
        s, why = self.inbox.poll(now)  # the tick takes it as the daemon's does
        assert s is not None, why
        return s.operator

    def hands_off(self) -> OperatorInput:
        """The dead-man held, the stick centred."""
        return self.sample([0.0, 0.0, 0.0])

    def toward(self, goal: str, gain: float = 1.0) -> OperatorInput:
        d = self.c.stage.target(goal).position - self.adapter.read_state().ee_position
        return self.sample(gain * d / max(float(np.linalg.norm(d)), 1e-9))

    def kinds(self) -> list[str]:
        return [k for k, _ in self.events]

    def phase(self) -> str | None:
        a = self.c.assistant
        return a.phase if a is not None else None

    def drive_to_commit(self, goal: str, limit: int = 600) -> None:
        """Steer straight at ``goal`` until the controller commits (to anything)."""
        for _ in range(limit):
            self.c.tick(self.toward(goal))
            if self.c.mode != Mode.TELEOP:
                return
        raise AssertionError("no commit")

    def commit(self, goal: str, limit: int = 2000) -> None:
        """Drive toward ``goal`` until the controller commits to it (confirm at the goal)."""
        c = self.c
        for _ in range(limit):
            if c.mode != Mode.TELEOP:
                break
            d = c.stage.target(goal).position - self.adapter.read_state().ee_position
            n = float(np.linalg.norm(d))
            c.tick(self.sample(d / n) if n > 0.01 else self.sample([0, 0, 0], confirm=True))
        assert c.mode == Mode.ASSIST
        assert c.committed == goal

    def drive(self, goal: str, ticks: int) -> None:
        """Steer toward a goal of the current stage (teleop) for a while."""
        for _ in range(ticks):
            if self.c.mode != Mode.TELEOP:
                return
            self.c.tick(self.toward(goal, 0.8))

    def until(self, done: Callable[[], bool], limit: int = 3000) -> None:
        """Tick hands off (dead-man held) until ``done``."""
        for _ in range(limit):
            if done():
                return
            self.c.tick(self.hands_off())
        raise AssertionError(f"not reached: mode {self.c.mode}, phase {self.phase()}")

    def command(self, command: str, argument: str | None = None) -> dict[str, Any]:
        body: dict[str, Any] = {"schema": 1, "command": command}
        if argument is not None:
            body["argument"] = argument
        return operator_command(self.c, CommandRequest.model_validate(body))


def operator_command(
    c: Controller,
    request: CommandRequest,
    plans: Callable[..., Any] | None = None,
    loaders: tuple[Callable[[str], Scene], Callable[[str], tuple[TaskGraph, Scene]]] = LOADERS,
) -> dict[str, Any]:
    """What the daemon does with an operator command, on the controller alone (no lease,
    no load queue; ``loaders``: the scene and task-graph loaders): the reply's detail."""
    match request.command:
        case "stop":
            c.stop("operator", "the command key")
            return {"mode": c.mode.value}
        case "reset":
            return c.reset()
        case "status":
            return {"mode": c.mode.value}
        case "load_scene" | "load_taskgraph":
            return c.install_now(c.prepare(request, *loaders, plans))
        case "release" | "take_control":
            raise InputError("the operator lease is the daemon's, not the controller's")
        case _:
            assert_never(request.command)

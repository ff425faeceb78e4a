"""One control tick of the daemon: modes, inference, commit, assistance, faults.

The controller owns the robot adapter and the intent observer; it is driven by the
service's loop (one :meth:`Controller.tick` per period) and by operator commands
(:meth:`Controller.command`, on the loop's thread). It does no I/O of its own: events go
to the ``emit`` callback, and each tick returns a :class:`TickRecord` for status and logs.

Modes:

- ``teleop``: the user drives, ``v = v_max * u``; the observer runs on the measured EE
  pose; at ``p >= p_thresh`` it commits and the mode becomes ``assist``.
- ``assist``: the robot carries out the stage action toward the committed goal; the
  cancel button or the stick held against the motion gives control back (``teleop``,
  inference restarts from where the arm is).
- ``idle``: the stage is done; the robot holds still until ``reset``.
- ``stopped``: the operator said stop; zero velocity until ``reset``.
- ``fault``: the adapter failed; zero velocity (when it can still be sent) until ``reset``.

In every mode, no valid joystick input for the deadman timeout means zero velocity: the
joystick is a dead-man switch for assistance too.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from legws_daemon.core.certificate import certify
from legws_daemon.core.geometry import FloatArray, Pose, quat_to_matrix
from legws_daemon.core.goals import MIN_GOAL_DISTANCE, GoalSet
from legws_daemon.core.observer import IntentObserver
from legws_daemon.core.params import Params
from legws_daemon.daemon.assist import (
    Assistant,
    CancelDetector,
    Primitive,
    pick_plan,
    place_plan,
    return_plan,
)
from legws_daemon.daemon.inbox import Sample
from legws_daemon.errors import HardwareError, InputError, LegwsError
from legws_daemon.formats.messages import CommandRequest
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.hardware.base import Adapter, RobotState
from legws_daemon.scene.scene import Layout, Scene

Emit = Callable[[str, dict[str, Any]], None]
#: Builds a connected adapter for a scene (the service decides which kind).
AdapterFactory = Callable[[Scene], Adapter]


@dataclass(frozen=True, slots=True)
class TickRecord:
    """Everything one tick measured and decided (for status, Rerun and benchmarks)."""

    tick: int
    mode: str
    state: RobotState | None
    joystick: FloatArray | None
    command: FloatArray
    posterior: dict[str, float]
    committed: str | None
    phase: str | None
    sample_received: float | None
    sample_seq: int | None
    sample_stamp: float | None  # the publisher's clock
    command_sent: float


@dataclass
class StageState:
    """The stage being run: its candidate goals and the layout they stand in."""

    name: str
    goal_names: tuple[str, ...]
    layout: Layout
    certificate: float
    goals_home: GoalSet
    extras: dict[str, Any] = field(default_factory=dict)


def goals_from(scene: Scene, layout: Layout, names: tuple[str, ...], x0: Pose) -> GoalSet:
    """The grasp poses of ``names`` in ``layout``, seen from the EE pose ``x0``."""
    g = scene.goal_set(layout, names)
    return GoalSet(g.names, g.positions, g.quaternions, g.symmetry, x0)


class Controller:
    """The daemon's per-tick logic (see the module docstring).

    Args:
        profile: the hardware profile.
        scene: the scene the robot works in.
        layout: the planned layout of the scene's movable objects.
        make_adapter: builds and connects the adapter for a scene.
        params: observer and certificate parameters (``dt`` and ``v_max`` from the profile).
        emit: receives events ``(kind, detail)``.
        clock: monotonic clock.
    """

    def __init__(
        self,
        profile: ProfileSpec,
        scene: Scene,
        layout: Layout,
        make_adapter: AdapterFactory,
        params: Params,
        emit: Emit,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.profile = profile
        self.params = params
        self.dt = 1.0 / profile.control.rate_hz
        self.emit = emit
        self.clock = clock
        self._make_adapter = make_adapter
        self.scene = scene
        self.adapter = make_adapter(scene)
        self.mode = "teleop"
        self.fault: str | None = None
        self.ticks = 0
        self.cancel = CancelDetector(self.dt)
        self.assistant: Assistant | None = None
        self.committed: str | None = None
        self.last_state: RobotState | None = None
        self._gripper: bool | None = None
        self._last_assist_v = np.zeros(3)
        self._hold: FloatArray = scene.home.rotation
        self.stage = self._new_stage("pick", scene.goal_names, layout)
        self.adapter.place_objects(layout)
        self.observer: IntentObserver | None = None
        self._restart_inference()

    # --- stages and inference -------------------------------------------------------
    def _new_stage(self, name: str, goal_names: tuple[str, ...], layout: Layout) -> StageState:
        goals_home = self.scene.goal_set(layout, goal_names)
        cert = certify(goals_home, self.params).objective
        return StageState(name, goal_names, dict(layout), cert, goals_home)

    def _restart_inference(self) -> None:
        """A fresh observer whose start pose is where the EE is now."""
        state = self._read_state_safely()
        if state is None:
            x0 = self.scene.home
        else:
            x0 = Pose(state.ee_position, state.ee_quaternion)
            self._hold = quat_to_matrix(state.ee_quaternion)
        try:
            goals = goals_from(self.scene, self.stage.layout, self.stage.goal_names, x0)
        except InputError:
            # the EE sits on a goal (closer than MIN_GOAL_DISTANCE): start from home instead
            goals = self.stage.goals_home
        self.observer = IntentObserver(goals, self.params)
        self.committed = None

    def posterior(self) -> dict[str, float]:
        if self.observer is None:
            return {}
        names = self.observer.goals.names
        return dict(zip(names, (float(p) for p in self.observer.posterior), strict=True))

    def live_slack(self) -> float | None:
        """The certificate seen from the current EE pose (how reliably intent can be read
        from here), or ``None`` when the EE sits on a goal."""
        state = self.last_state
        if state is None or self.mode != "teleop":
            return None
        x0 = Pose(state.ee_position, state.ee_quaternion)
        goals = self.stage.goals_home
        if np.min(np.linalg.norm(goals.positions - x0.position, axis=1)) < 2 * MIN_GOAL_DISTANCE:
            return None
        live = GoalSet(goals.names, goals.positions, goals.quaternions, goals.symmetry, x0)
        return certify(live, self.params).objective

    # --- the tick -------------------------------------------------------------------------
    def _read_state_safely(self) -> RobotState | None:
        try:
            return self.adapter.read_state()
        except LegwsError:
            return None

    def tick(self, sample: Sample | None) -> TickRecord:
        """Run one control period with the newest valid joystick sample (or ``None``)."""
        self.ticks += 1
        axes = np.array(sample.message.axes) if sample is not None else None
        velocity = np.zeros(3)
        hold: FloatArray | None = None
        phase: str | None = None
        state: RobotState | None = None
        if self.mode != "fault":
            try:
                state = self.adapter.read_state()
            except LegwsError as err:
                self._to_fault(f"read_state: {err}")
        self.last_state = state if state is not None else self.last_state
        if state is not None:
            if self.mode == "teleop":
                confirm = sample is not None and sample.message.buttons.confirm
                velocity, hold = self._teleop(state, axes, confirm)
            if self.mode == "assist" and self.assistant is not None:
                velocity, hold, phase = self._assist(state, sample, axes)
        sent = self._send(velocity, hold)
        return TickRecord(
            tick=self.ticks,
            mode=self.mode,
            state=state,
            joystick=axes,
            command=sent,
            posterior=self.posterior(),
            committed=self.committed,
            phase=phase,
            sample_received=sample.received if sample is not None else None,
            sample_seq=sample.message.seq if sample is not None else None,
            sample_stamp=sample.message.stamp if sample is not None else None,
            command_sent=self.clock(),
        )

    def _teleop(
        self, state: RobotState, axes: FloatArray | None, confirm: bool
    ) -> tuple[FloatArray, FloatArray | None]:
        obs = self.observer
        assert obs is not None
        post = obs.update(state.ee_position, state.ee_quaternion)
        if obs.committed is not None:
            goal = obs.goals.names[obs.committed]
            self._commit(goal, float(post[obs.committed]), state, confirmed=False)
            return np.zeros(3), None  # assistance starts next tick from a fresh state
        if confirm:
            # the user vouches for the most likely goal (e.g. the stick is already there)
            best = int(np.argmax(post))
            self._commit(obs.goals.names[best], float(post[best]), state, confirmed=True)
            return np.zeros(3), None
        if axes is None:
            return np.zeros(3), None  # deadman: nothing moves, not even the orientation
        return self.profile.control.v_max * axes, self._hold

    def _commit(self, goal: str, p: float, state: RobotState, *, confirmed: bool) -> None:
        self.committed = goal
        g = self.stage.goals_home
        i = g.index(goal)
        R_now = quat_to_matrix(state.ee_quaternion)
        plan: list[Primitive] = pick_plan(g.positions[i], g.rotations[i], int(g.symmetry[i]), R_now)
        self._start_assist(plan, goal)
        t = self.observer.ticks * self.dt if self.observer is not None else 0.0
        self.emit(
            "commit",
            {"goal": goal, "p": round(p, 4), "tick": self.ticks, "seconds": round(t, 3),
             "stage": self.stage.name, "confirmed": confirmed, "posterior": self.posterior()},
        )  # fmt: skip

    def _start_assist(self, plan: list[Primitive], target: str) -> None:
        self.assistant = Assistant(plan, self.profile.control.assist_speed, self.dt, target)
        self.cancel.reset()
        self._last_assist_v = np.zeros(3)
        self.mode = "assist"

    def _assist(
        self, state: RobotState, sample: Sample | None, axes: FloatArray | None
    ) -> tuple[FloatArray, FloatArray | None, str]:
        a = self.assistant
        assert a is not None
        button = sample is not None and sample.message.buttons.cancel
        reason = self.cancel.update(axes, self._last_assist_v, button)
        if reason is not None and a.target != "home":
            self.mode = "teleop"
            self.emit("cancel", {"reason": reason, "goal": a.target, "phase": a.phase})
            self.assistant = None
            self._restart_inference()
            return np.zeros(3), None, "cancelled"
        step = a.step(state.ee_position, quat_to_matrix(state.ee_quaternion), sample is not None)
        if step.grip is not None and step.grip != self._gripper:
            try:
                self.adapter.grip(step.grip)
                self._gripper = step.grip
            except LegwsError as err:
                self._to_fault(f"grip: {err}")
                return np.zeros(3), None, step.phase
        self._last_assist_v = step.velocity
        if step.failed is not None:
            self.emit("warning", {"assist": a.target, "phase": step.phase, "error": step.failed})
            self.assistant = None
            self.mode = "teleop"
            self._restart_inference()
            return np.zeros(3), None, step.phase
        if step.done:
            self._finish_assist(a)
            return np.zeros(3), None, step.phase
        if sample is None:
            return np.zeros(3), None, step.phase  # deadman pauses the plan
        return step.velocity, step.hold, step.phase

    def _finish_assist(self, a: Assistant) -> None:
        self.assistant = None
        if a.target == "home":
            self.mode = "teleop"
            self._restart_inference()
            self.emit("recovered" if self.fault else "reset", {"stage": self.stage.name})
            self.fault = None
            return
        self.mode = "idle"
        self.emit("stage_done", {"stage": self.stage.name, "goal": a.target, "ticks": self.ticks})

    def _send(self, velocity: FloatArray, hold: FloatArray | None) -> FloatArray:
        if self.mode in ("fault", "stopped", "idle"):
            velocity, hold = np.zeros(3), None
        try:
            return self.adapter.send_velocity(velocity, hold)
        except LegwsError as err:
            if self.mode != "fault":
                self._to_fault(f"send_velocity: {err}")
            return np.zeros(3)

    def _to_fault(self, reason: str) -> None:
        first = self.mode != "fault"
        self.mode = "fault"
        self.fault = reason
        self.assistant = None
        if first:
            self.emit("fault", {"error": reason})
        # if even this fails, the robot side's own deadman stops it when commands stop
        with contextlib.suppress(LegwsError):
            self.adapter.halt()

    # --- operator commands ------------------------------------------------------------
    def command(self, request: CommandRequest, scenes: Callable[[str], Scene]) -> dict[str, Any]:
        """Carry out an operator command; returns the reply's detail."""
        if request.command == "stop":
            self.mode = "stopped"
            self.assistant = None
            self._send(np.zeros(3), None)
            self.emit("stop", {"mode": self.mode})
            return {"mode": self.mode}
        if request.command == "reset":
            return self._reset()
        if request.command == "load_scene":
            assert request.argument is not None
            return self.load_scene(scenes(request.argument), None)
        if request.command == "load_taskgraph":
            raise InputError("task graphs are not loaded by this daemon yet", field="command")
        return {"mode": self.mode}

    def _reset(self) -> dict[str, Any]:
        """Clear a stop or fault, put back what the robot holds, go home, infer again."""
        if self.mode == "fault":
            state = self._read_state_safely()
            if state is None:
                raise HardwareError(f"the robot is still failing: {self.fault}")
        state = self._read_state_safely()
        if state is None:
            raise HardwareError("no robot state")
        R = quat_to_matrix(state.ee_quaternion)
        plan: list[Primitive] = []
        holding = self.committed is not None and self._gripper
        if holding and self.committed in self.stage.goals_home.names:
            g = self.stage.goals_home
            plan += place_plan(g.positions[g.index(self.committed)], R)
        plan += return_plan(self.scene.home.position, self.scene.home.rotation)
        self._start_assist(plan, "home")
        return {"mode": self.mode, "plan": [p.label for p in plan]}

    def load_scene(self, scene: Scene, layout: Layout | None) -> dict[str, Any]:
        """Swap to another scene (the robot stops first); the stage restarts."""
        self._send(np.zeros(3), None)
        old = self.adapter
        adapter = self._make_adapter(scene)
        old.disconnect()
        self.adapter = adapter
        self.scene = scene
        lay = layout if layout is not None else scene.default_layout()
        self.stage = self._new_stage("pick", scene.goal_names, lay)
        adapter.place_objects(lay)
        self.mode, self.fault, self.assistant, self._gripper = "teleop", None, None, None
        self._restart_inference()
        self.emit("loaded", {"scene": scene.name, "certificate": self.stage.certificate})
        return {"scene": scene.name, "certificate": self.stage.certificate}

    def shutdown(self) -> None:
        """Zero velocity and disconnect (idempotent)."""
        with contextlib.suppress(LegwsError):
            self.adapter.halt()
        self.adapter.disconnect()

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
    Grip,
    Primitive,
    dip_plan,
    feed_plan,
    home_move,
    pick_plan,
    place_plan,
    return_plan,
)
from legws_daemon.daemon.inbox import Sample
from legws_daemon.design.plan import Plan
from legws_daemon.errors import HardwareError, InputError, LegwsError
from legws_daemon.formats.messages import CommandRequest
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.hardware.base import Adapter, RobotState
from legws_daemon.scene.scene import Layout, Scene
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.runner import TaskRun, scene_graph
from legws_daemon.task.targets import Target, goal_set, target

Emit = Callable[[str, dict[str, Any]], None]
#: The assistance target of a reset (going home), which no cancel interrupts.
RESET_TARGET = "(reset)"
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
    """The stage being run: its candidate goals' poses and the layout they stand in.

    ``goals_home`` (the goal set seen from home) and ``certificate`` are ``None`` for a
    stage with a single candidate, which needs no inference.
    """

    name: str
    targets: list[Target]
    layout: Layout
    certificate: float | None
    goals_home: GoalSet | None
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def goal_names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.targets)

    def target(self, goal: str) -> Target:
        for t in self.targets:
            if t.name == goal:
                return t
        raise KeyError(goal)


class Controller:
    """The daemon's per-tick logic (see the module docstring).

    Args:
        profile: the hardware profile.
        scene: the scene the robot works in.
        layout: the planned layout of the scene's movable objects.
        make_adapter: builds and connects the adapter for a scene.
        params: observer and certificate parameters (``dt`` and ``v_max`` from the profile).
        emit: receives events ``(kind, detail)``.
        graph: the task graph to run (default: pick one of the scene's candidate goals).
        plan: stage-specific layouts of the graph (``legws plan``): at each decision the
            optimised objects go to their planned poses (the stand-in moves them; on a real
            robot they are shown as placement targets and a person places them).
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
        graph: TaskGraph | None = None,
        plan: Plan | None = None,
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
        self.observer: IntentObserver | None = None
        self._gripper: bool | None = None
        self._auto_commit = True
        self.decisions = 0
        self._last_assist_v = np.zeros(3)
        self._hold: FloatArray = scene.home.rotation
        self.planned: Layout = dict(layout)  # where the objects should stand
        self.observed: Layout = {}  # where a tracker says they are (a real robot)
        self.layout: Layout = dict(layout)  # what inference uses: planned, then observed
        self._misplaced: tuple[int, str] | None = None
        self.graph = graph if graph is not None else scene_graph(scene)
        self.plan = plan
        self.task = TaskRun(self.graph, scene)
        self.adapter.place_objects(self.layout)
        self.stage = self._begin_stage()

    # --- stages and inference -------------------------------------------------------
    def _begin_stage(self) -> StageState:
        """Targets of the stage(s) that come next; inference starts (or, with a single
        candidate, the commit is immediate)."""
        self.decisions += 1
        self._apply_plan()
        targets = self.task.targets(self.layout) if not self.task.finished else []
        goals_home = cert = None
        if len(targets) >= 2:
            goals_home = goal_set(targets, self.scene.home)
            cert = certify(goals_home, self.params).objective
        self.stage = StageState(self.task.label, targets, dict(self.layout), cert, goals_home)
        self.committed = None
        self.observer = None
        if self.task.finished:
            self.mode = "idle"
            self.emit("task_done", {"task": self.graph.name, "history": self.task.history})
        elif len(targets) == 1:
            self._auto_commit = True
            self.mode = "teleop"
            state = self._read_state_safely()
            if state is not None:
                self._commit(targets[0].name, 1.0, state, confirmed=False, single=True)
        else:
            self.mode = "teleop"
            self._restart_inference()
        return self.stage

    def _apply_plan(self) -> None:
        """Move this decision's optimised objects to their planned poses."""
        if self.plan is None or self.task.finished:
            return
        try:
            decision = self.plan.decision(self.task.label)
        except InputError:
            return  # the plan does not know this decision: keep the layout
        planned = self.plan.layout_for(decision.label)
        moves = {n: planned[n] for n in decision.optimised if n in planned}
        if not moves or all(self.planned.get(n) == p for n, p in moves.items()):
            return
        self.planned.update(moves)
        self.layout = {**self.planned, **self.observed}
        if not self.adapter.place_objects(moves):
            self.emit(
                "warning",
                {"place": {n: {"x": p.x, "y": p.y, "yaw": p.yaw} for n, p in moves.items()},
                 "stage": self.task.label, "certificate": decision.certificate},
            )  # fmt: skip

    def _restart_inference(self) -> None:
        """A fresh observer whose start pose is where the EE is now."""
        self.committed = None
        if self.stage.goals_home is None:
            self.observer = None
            return
        state = self._read_state_safely()
        goals = self.stage.goals_home
        if state is not None:
            x0 = Pose(state.ee_position, state.ee_quaternion)
            self._hold = quat_to_matrix(state.ee_quaternion)
            with contextlib.suppress(InputError):  # the EE sits on a goal: start from home
                goals = goal_set(self.stage.targets, x0)
        self.observer = IntentObserver(goals, self.params)

    def observe(self, poses: Layout) -> None:
        """Object poses reported on ``legws/<robot>/objects`` (a real robot's tracker).

        Inference of the next decision uses them. The current decision's certificate is
        recomputed from them; when it is no longer positive (and the plan's was), a
        ``warning`` event names the object to move back and where to.
        """
        known = {n: p for n, p in poses.items() if n in self.scene.movable}
        if not known:
            return
        self.observed.update(known)
        self.layout = {**self.planned, **self.observed}
        targets = self.stage.targets
        if len(targets) < 2 or self.task.finished:
            return
        names = [t.name for t in targets]
        current = self._decision_certificate(self.layout)
        self.stage.extras["observed_certificate"] = current
        planned = self.stage.certificate
        if current > 0 or planned is None or planned <= 0:
            self._misplaced = None
            return
        best, best_gain = None, 0.0
        for n in names:
            if n in self.observed and n in self.planned:
                trial = {**self.layout, n: self.planned[n]}
                gain = self._decision_certificate(trial) - current
                if gain > best_gain:
                    best, best_gain = n, gain
        if best is None:
            return
        key = (self.decisions, best)
        if key == self._misplaced:
            return
        self._misplaced = key
        to = self.planned[best]
        self.emit(
            "warning",
            {"certificate": round(current, 4), "planned_certificate": round(planned, 4),
             "move": best, "to": {"x": to.x, "y": to.y, "yaw": to.yaw},
             "stage": self.stage.name},
        )  # fmt: skip

    def _decision_certificate(self, layout: Layout) -> float:
        run = self.task
        targets = run.targets(layout)
        return certify(goal_set(targets, self.scene.home), self.params).objective

    def posterior(self) -> dict[str, float]:
        if self.observer is None:
            return {}
        names = self.observer.goals.names
        return dict(zip(names, (float(p) for p in self.observer.posterior), strict=True))

    def live_slack(self) -> float | None:
        """The certificate seen from the current EE pose (how reliably intent can be read
        from here), or ``None`` (no inference, or the EE sits on a goal)."""
        state, goals = self.last_state, self.stage.goals_home
        if state is None or self.mode != "teleop" or goals is None:
            return None
        x0 = Pose(state.ee_position, state.ee_quaternion)
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
        if obs is None:
            # a single-candidate stage: it starts by itself, but after a failed attempt
            # only when the user confirms (no retrying for ever on its own)
            if len(self.stage.targets) == 1 and (self._auto_commit or confirm):
                self._commit(self.stage.targets[0].name, 1.0, state, confirmed=confirm, single=True)
                return np.zeros(3), None
            if axes is None:
                return np.zeros(3), None
            return self.profile.control.v_max * axes, self._hold
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

    def _commit(
        self, goal: str, p: float, state: RobotState, *, confirmed: bool, single: bool = False
    ) -> None:
        self.committed = goal
        t = self.stage.target(goal)
        R_now = quat_to_matrix(state.ee_quaternion)
        plan: list[Primitive]
        if t.action == "pick" or t.action == "return":
            plan = pick_plan(t.position, t.rotation, t.symmetry, R_now)
            if t.action == "return":  # put it back: lower onto the spot and let go
                plan = [plan[0], plan[1], Grip("release", closed=False), plan[3]]
        elif t.action == "place":
            plan = place_plan(t.position, R_now)
        elif t.action == "dip":
            plan = dip_plan(t.position, R_now)
        else:
            plan = feed_plan(t.position, t.rotation, t.symmetry, R_now)
        plan.append(home_move(self.scene.home.position, self.scene.home.rotation))
        self._start_assist(plan, goal)
        seconds = self.observer.ticks * self.dt if self.observer is not None else 0.0
        self.emit(
            "commit",
            {"goal": goal, "p": round(p, 4), "tick": self.ticks, "seconds": round(seconds, 3),
             "stage": t.stage, "decision": self.stage.name, "action": t.action,
             "confirmed": confirmed, "single": single, "certificate": self.stage.certificate,
             "posterior": self.posterior()},
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
        if reason is not None and a.target != RESET_TARGET:
            self._cancel(a, reason)
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
            self._auto_commit = False
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

    def _cancel(self, a: Assistant, reason: str) -> None:
        """Give control back. Before the plan's gripper acted, the same stage's inference
        restarts from here; after it (grasped, released), the stage's effect has happened:
        the stage counts as done and the next one starts from here."""
        self.assistant = None
        self.emit("cancel", {"reason": reason, "goal": a.target, "phase": a.phase})
        if a.gripper_acted:
            self.task.advance(a.target, self.layout)
            self.emit("stage_done", {"goal": a.target, "cancelled": True, "ticks": self.ticks})
            self._begin_stage()
            if self.mode == "assist":
                return  # a single-candidate stage follows: the robot goes on
        self.mode = "teleop"
        self._restart_inference()

    def _finish_assist(self, a: Assistant) -> None:
        self.assistant = None
        if a.target == RESET_TARGET:
            self.emit("recovered" if self.fault else "reset", {"task": self.graph.name})
            self.fault = None
            self.task = TaskRun(self.graph, self.scene)
            self.adapter.place_objects(self.layout)
            self._begin_stage()
            return
        self._stage_done(a.target)

    def _stage_done(self, goal: str) -> None:
        stage = self.task.advance(goal, self.layout)
        self.emit(
            "stage_done",
            {"stage": stage.name, "goal": goal, "action": stage.action, "ticks": self.ticks},
        )
        self._begin_stage()

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
    def command(
        self,
        request: CommandRequest,
        scenes: Callable[[str], Scene],
        graphs: Callable[[str], tuple[TaskGraph, Scene]],
    ) -> dict[str, Any]:
        """Carry out an operator command; returns the reply's detail.

        Args:
            request: the validated command.
            scenes / graphs: load a scene / a task graph (and its scene) by name.
        """
        if request.command == "stop":
            self.mode = "stopped"
            self.assistant = None
            self._send(np.zeros(3), None)
            self.emit("stop", {"mode": self.mode})
            return {"mode": self.mode}
        if request.command == "reset":
            return self._reset()
        if request.command == "status":
            return {"mode": self.mode}
        assert request.argument is not None
        if request.command == "load_scene":
            return self.load(scenes(request.argument), None, None)
        if request.command == "load_taskgraph":
            graph, scene = graphs(request.argument)
            if scene.name == self.scene.name:
                scene = self.scene
            return self.load(scene, None, graph)
        return {"mode": self.mode}

    def _reset(self) -> dict[str, Any]:
        """Clear a stop or fault and start the task again: put back what the robot holds,
        go home, objects back at the layout (on the stand-in), infer from the first stage."""
        state = self._read_state_safely()
        if state is None:
            raise HardwareError(f"the robot is still failing: {self.fault or 'no state'}")
        plan: list[Primitive] = []
        held = self.task.held if self._gripper else None
        if self._gripper and held is not None:
            t = target(
                self.scene, self.layout, "reset", "return", held, held, self.task.picked_from
            )
            back = pick_plan(
                t.position, t.rotation, t.symmetry, quat_to_matrix(state.ee_quaternion)
            )
            plan += [back[0], back[1]]
        plan += return_plan(self.scene.home.position, self.scene.home.rotation)
        self.observer = None
        self._start_assist(plan, RESET_TARGET)
        return {"mode": self.mode, "plan": [p.label for p in plan]}

    def load(self, scene: Scene, layout: Layout | None, graph: TaskGraph | None) -> dict[str, Any]:
        """Swap to another scene or task graph (the robot stops first); the task restarts."""
        self._send(np.zeros(3), None)
        if scene is not self.scene:
            old = self.adapter
            adapter = self._make_adapter(scene)
            old.disconnect()
            self.adapter = adapter
            self.scene = scene
        self.layout = dict(layout if layout is not None else scene.default_layout())
        self.graph = graph if graph is not None else scene_graph(scene)
        self.plan = None  # a plan belongs to the graph it was made for
        self.planned = dict(self.layout)
        self.observed = {}
        self.task = TaskRun(self.graph, scene)
        self.fault, self.assistant, self._gripper = None, None, None
        self.adapter.place_objects(self.layout)
        self._begin_stage()
        detail = {"scene": scene.name, "task": self.graph.name, "stage": self.stage.name,
                  "certificate": self.stage.certificate}  # fmt: skip
        self.emit("loaded", detail)
        return detail

    def shutdown(self) -> None:
        """Zero velocity and disconnect (idempotent)."""
        with contextlib.suppress(LegwsError):
            self.adapter.halt()
        self.adapter.disconnect()

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

``reset`` with an object in the gripper first puts it back where it was taken from (see
:meth:`Controller._reset`): the pick, reversed, to the EE pose the gripper closed at
(:func:`~legws_daemon.daemon.assist.put_back_plan`). When that pose cannot be reached
(outside the workspace box, or a move makes no progress for
:data:`~legws_daemon.daemon.assist.STALL_SECONDS`), the object is *set down* instead, with
a ``warning`` event ``{"reset": "set_down", ...}``: turned back to the orientation it was
carried in when the reset began, carried level over the spot it came from and released
with its bottom :data:`~legws_daemon.task.targets.SET_DOWN_CLEARANCE` above the table.
If that fails too: straight down where it is, at the orientation it has; then let go
right there. Never from higher than :data:`~legws_daemon.task.targets.MAX_SET_DOWN_DROP`:
rather than that, the reset gives control back (a warning) or, when no release pose is low
enough at all, is refused once (a person takes the object; the next reset opens the
gripper where it is). Then the gripper is open and the robot goes home.

In every mode, no valid joystick input for the deadman timeout means zero velocity: the
joystick is a dead-man switch for assistance too.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from legws_daemon.core.certificate import certify
from legws_daemon.core.geometry import FloatArray, Pose, quat_to_matrix, rotation_angle
from legws_daemon.core.goals import MIN_GOAL_DISTANCE, GoalSet
from legws_daemon.core.observer import IntentObserver
from legws_daemon.core.params import Params
from legws_daemon.daemon.assist import (
    LIFT_HEIGHT,
    POSITION_TOLERANCE,
    PREGRASP_DISTANCE,
    ROTATION_TOLERANCE,
    STALL_SECONDS,
    Assistant,
    CancelDetector,
    Move,
    Primitive,
    dip_plan,
    feed_plan,
    grasp_rotation,
    home_move,
    pick_plan,
    place_plan,
    put_back_plan,
    return_plan,
    set_down_plan,
)
from legws_daemon.daemon.inbox import Sample
from legws_daemon.errors import HardwareError, InfeasibleError, InputError, LegwsError
from legws_daemon.formats.messages import CommandRequest
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.hardware.base import Adapter, RobotState
from legws_daemon.scene.scene import Layout, Scene
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import Plan
from legws_daemon.task.runner import TaskRun, scene_graph
from legws_daemon.task.targets import MAX_SET_DOWN_DROP, Held, Target, goal_set, held_object

Emit = Callable[[str, dict[str, Any]], None]
#: The assistance target of a reset (going home), which no cancel interrupts.
RESET_TARGET = "(reset)"
#: Builds a connected adapter for a scene (the service decides which kind).
AdapterFactory = Callable[[Scene], Adapter]
#: The moves of a reset's put-back and set-down before the release: their failure sets the
#: object down (one step further each time, see ``Controller._reset_fallback``).
PUT_BACK_PHASES = ("rise", "carry", "roll", "tilt", "approach", "reach")
SET_DOWN_PHASES = ("turn_back", "over", "lower")
#: Targets of a reset's moves stay this far inside the workspace box, m.
BOX_MARGIN = 0.005


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
    stage with a single candidate, which needs no inference. ``observed_certificate`` is
    the certificate recomputed from object poses a tracker reported (``None`` until then).
    """

    name: str
    targets: list[Target]
    layout: Layout
    certificate: float | None
    goals_home: GoalSet | None
    observed_certificate: float | None = None

    @property
    def current_certificate(self) -> float | None:
        """What status reports: the observed certificate once there is one, else the plan's."""
        return self.certificate if self.observed_certificate is None else self.observed_certificate

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
        self._held: Held | None = None  # what the gripper closed on, and how
        self._drop_asked = False  # a reset was refused: the next one lets go where it is
        self._carried: FloatArray = scene.home.rotation  # the EE orientation a reset began at
        self._fallbacks = 0  # how many times the running reset fell back
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
        self.stage.observed_certificate = current
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
        if t.action == "pick":
            plan = pick_plan(t.position, t.rotation, t.symmetry, R_now)
        elif t.action == "return":  # put it back: the pick reversed, at the grasp it took
            held = self._held if self._held is not None and self._held.name == goal else None
            g, R = (
                (held.position, held.rotation)
                if held is not None
                else (t.position, grasp_rotation(t.rotation, t.symmetry, R_now))
            )
            plan = self._put_back_moves(g, R, state)
        elif t.action == "place":
            plan = place_plan(t.position, R_now)
        elif t.action == "dip":
            plan = dip_plan(t.position, R_now)
        else:
            plan = feed_plan(t.position, t.rotation, t.symmetry, R_now)
        plan.append(self._home())
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
            self._record_grip(a, state, step.grip)
        self._last_assist_v = step.velocity
        if step.failed is not None:
            if a.target == RESET_TARGET and self._reset_fallback(state, step.phase, step.failed):
                return np.zeros(3), None, step.phase
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

    def _record_grip(self, a: Assistant, state: RobotState, closed: bool) -> None:
        """Remember what the gripper closed on, and the EE pose it took it at (a reset
        puts it back there); forget it when the gripper opens."""
        if not closed:
            self._held = None
        elif a.target in self.scene.movable:
            R = quat_to_matrix(state.ee_quaternion)
            self._held = held_object(self.scene, self.layout, a.target, state.ee_position, R)

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
        # the message schema admits no other command: one reaching here is a bug, not a no-op
        raise InputError(f"unknown command {request.command!r}", field="command")

    def _reset(self) -> dict[str, Any]:
        """Clear a stop or fault and start the task again: put back what the robot holds
        (or set it down, see the module docstring), go home, objects back at the layout
        (on the stand-in), infer from the first stage.

        Raises:
            HardwareError: the robot still fails.
            InfeasibleError: the robot holds an object it can set down nowhere without
                dropping it from higher than ``MAX_SET_DOWN_DROP`` (the workspace box
                keeps the EE too high): a person takes it from the gripper, and the next
                ``reset`` opens the gripper where it is.
        """
        state = self._read_state_safely()
        if state is None:
            raise HardwareError(f"the robot is still failing: {self.fault or 'no state'}")
        held = self._held if self._gripper is not False else None
        plan: list[Primitive] | None = None
        self._carried = quat_to_matrix(state.ee_quaternion)
        self._fallbacks = 0
        if held is not None:
            plan = self._put_back(held, state)
            if plan is None:
                self._fallbacks = 1
                plan = self._set_down(held, state, over=True)
                if plan is not None:
                    outside = "the grasp pose is outside the workspace box"
                    self._warn_set_down(held, "reset", outside)
            if plan is None and not self._drop_asked:
                self._drop_asked = True
                raise InfeasibleError(
                    f"the robot holds '{held.name}' and cannot set it down within the "
                    f"workspace box: take it from the gripper, then reset again (the gripper "
                    f"opens where it is)"
                )
        if plan is None:  # nothing held (or a person has taken it): open, go home
            plan = return_plan(self.scene.home.position, self.scene.home.rotation)
        self._drop_asked = False
        self.observer = None
        self._start_assist(plan, RESET_TARGET)
        return {"mode": self.mode, "plan": [p.label for p in plan]}

    def _in_box(self, p: FloatArray) -> FloatArray:
        """``p`` moved inside the adapter's workspace box, ``BOX_MARGIN`` from its faces."""
        box = self.adapter.box
        return np.asarray(np.clip(p, box.lower + BOX_MARGIN, box.upper - BOX_MARGIN), np.float64)

    def _carry_height(self, grasp: FloatArray, rotation: FloatArray) -> float:
        """Height to carry a held object at toward a grasp pose: ``LIFT_HEIGHT`` above
        the higher of the grasp and pre-grasp poses (inside the box)."""
        pre = grasp - PREGRASP_DISTANCE * rotation[:, 2]
        top = self.adapter.box.upper[2] - BOX_MARGIN
        return float(min(max(grasp[2], pre[2]) + LIFT_HEIGHT, top))

    def _home(self) -> Move:
        return home_move(self.scene.home.position, self.scene.home.rotation)

    def _put_back(self, held: Held, state: RobotState) -> list[Primitive] | None:
        """The reset's plan to put ``held`` back at the grasp pose it was taken at, or
        ``None`` when that pose or its pre-grasp pose lies outside the workspace box."""
        g, R = held.position, held.rotation
        pre = g - PREGRASP_DISTANCE * R[:, 2]
        box = self.adapter.box
        if not (box.contains(g, POSITION_TOLERANCE) and box.contains(pre, 2 * POSITION_TOLERANCE)):
            return None
        return [*self._put_back_moves(g, R, state, STALL_SECONDS), self._home()]

    def _put_back_moves(
        self,
        grasp: FloatArray,
        rotation: FloatArray,
        state: RobotState,
        patience: float | None = None,
    ) -> list[Primitive]:
        """:func:`put_back_plan` to the grasp pose from the EE pose now, carried at
        :meth:`_carry_height`, ending turned to the home orientation."""
        R_now = quat_to_matrix(state.ee_quaternion)
        carry = self._carry_height(grasp, rotation)
        return put_back_plan(
            grasp, rotation, state.ee_position, R_now, carry, self.scene.home.rotation, patience
        )

    def _set_down(
        self, held: Held, state: RobotState, *, over: bool, here: bool = False
    ) -> list[Primitive] | None:
        """A plan that sets ``held`` down and goes home.

        ``over``: first turn back (in place) to the orientation the object was carried
        in when the reset began, then set it down at that orientation with its centre
        over the spot it came from. Otherwise at the orientation it has now: straight
        below the EE, or (``here``) released right where the EE is. ``None`` when the
        object's bottom would be more than ``MAX_SET_DOWN_DROP`` above the table at the
        release.
        """
        p = np.asarray(state.ee_position, dtype=np.float64)
        R_now = quat_to_matrix(state.ee_quaternion)
        R = self._carried if over else R_now
        table = self.scene.workspace.table_height
        # over the spot it came from, or straight below where the object is now
        spot = held.set_down_position(R, table, None if over else p + R_now @ held.center)
        release = p if here else self._in_box(spot)
        if held.bottom(release, R) - table > MAX_SET_DOWN_DROP:
            return None
        top = float(self.adapter.box.upper[2]) - BOX_MARGIN
        retreat = min(float(release[2]) + LIFT_HEIGHT, top)
        patience = None if here else STALL_SECONDS
        plan: list[Primitive] = []
        if float(rotation_angle(R_now, R)) >= ROTATION_TOLERANCE:
            plan.append(Move("turn_back", p, R, 2 * POSITION_TOLERANCE, patience))
        plan += set_down_plan(p, R, release, retreat, self.scene.home.rotation, patience)
        return [*plan, self._home()]

    def _reset_fallback(self, state: RobotState, phase: str, error: str) -> bool:
        """A move of the reset failed before the release: set the held object down
        instead. Each failure goes one step further: the put-back failed — set it down
        over its spot; that failed — straight down where it is; that failed — let go
        right here (if low enough). ``False``: nothing (more) to fall back to."""
        held = self._held
        if (
            held is None
            or self._gripper is False
            or phase not in (*PUT_BACK_PHASES, *SET_DOWN_PHASES)
        ):
            return False
        self._fallbacks += 1
        plan: list[Primitive] | None = None
        if self._fallbacks == 1:
            plan = self._set_down(held, state, over=True)
        elif self._fallbacks == 2:
            plan = self._set_down(held, state, over=False)
        elif self._fallbacks == 3:
            plan = self._set_down(held, state, over=False, here=True)
        if plan is None:
            return False
        self._warn_set_down(held, phase, error)
        self._start_assist(plan, RESET_TARGET)
        return True

    def _warn_set_down(self, held: Held, phase: str, reason: str) -> None:
        self.emit(
            "warning",
            {"reset": "set_down", "object": held.name, "phase": phase, "reason": reason},
        )

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
        if self.adapter.place_objects(self.layout):
            self._held = None  # the stand-in let go of it and put it back
        self._drop_asked = False
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

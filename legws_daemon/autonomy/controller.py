"""One control tick of shared autonomy: inference, commit, assistance, faults.

The controller owns the robot adapter, the motion planner and the intent observer. It is
driven by a loop — the daemon's real-time loop, or ``legws eval`` in simulated time — one
:meth:`Controller.tick` per period, and by operator commands (:meth:`Controller.command`,
on the loop's thread). It does no I/O of its own: events go to ``emit`` as typed records
(:mod:`.events`), and each tick returns a :class:`TickRecord`.

Each tick reads the robot state once and hands that state to everything that needs it:
the observer, the assistance, the command's safety envelope, and (through the record)
status and telemetry. Modes and transitions: :mod:`.modes`. In every mode, no valid
joystick input means zero velocity: the joystick is a dead-man switch for assistance too.

Before the commit the profile's ``control.assist`` policy may add the robot's motion to the
operator's (:mod:`legws_daemon.core.arbitration`: ``blend``, ``hindsight``; ``none`` never
commits); the observer then follows the operator's own integrated input, never the EE's
blended path. The stick held against the robot's goal is an override (:mod:`.override`):
control comes back ramped, inference restarts.

Every certificate it computes (the decision's from home, the live slack, the placed
layout's J and K, those its events carry) is for ``operator`` when one is given (a person's
operator model, method.md §10), else for section 2's user. In mode ``calibrate``
(:meth:`Controller.start_calibration`, :mod:`.calibration`) the user drives to one target
at a time; nothing is inferred, committed or assisted.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from typing import Any, assert_never

import numpy as np

from legws_daemon.autonomy.assistant import Assistant
from legws_daemon.autonomy.calibration import CalibrationRun, targets_for
from legws_daemon.autonomy.cancel import CancelDetector
from legws_daemon.autonomy.decision import (
    Inference,
    StageState,
    certificate_of,
    commit_for,
    decision_goals,
    live_slack,
    slack_for,
)
from legws_daemon.autonomy.events import (
    AssistFailed,
    Cancel,
    Commit,
    Emit,
    Fault,
    Loaded,
    NoPlan,
    Override,
    PlaceObjects,
    PlanDropped,
    Recovered,
    Reset,
    StageDone,
    Stop,
    TaskDone,
)
from legws_daemon.autonomy.inputs import (
    Cartesian,
    Command,
    Joints,
    OperatorInput,
    TickRecord,
    zero,
)
from legws_daemon.autonomy.layouts import LayoutBook
from legws_daemon.autonomy.modes import (
    RESET_LABEL,
    STILL,
    Activity,
    Gripper,
    Mode,
    ModeMachine,
    SingleCommit,
)
from legws_daemon.autonomy.override import HandBack, OverrideDetector
from legws_daemon.autonomy.placing import PlacementReport
from legws_daemon.autonomy.recovery import Recovery
from legws_daemon.core.arbitration import Blended, blend, hindsight, slew
from legws_daemon.core.geometry import FloatArray, axis_rotation
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.errors import HardwareError, InfeasibleError, InputError, LegwsError
from legws_daemon.formats.messages import CommandRequest
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.hardware.base import Adapter, RobotState
from legws_daemon.robot.motion import Move, Primitive
from legws_daemon.robot.planner import MotionPlanner
from legws_daemon.robot.world import resolve_arm
from legws_daemon.safety.envelope import clamp_ee_velocity
from legws_daemon.scene.scene import Layout, Scene
from legws_daemon.task.actions import PlanContext, action
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import Plan, PlannedDecision
from legws_daemon.task.runner import TaskRun, scene_graph
from legws_daemon.task.targets import Held, held_object

#: Builds a connected adapter for a scene (the service decides which kind).
AdapterFactory = Callable[[Scene], Adapter]
#: The operator commands that load something (prepared off the control loop by the daemon).
LOADS = frozenset({"load_scene", "load_taskgraph"})


@dataclass
class PreparedLoad:
    """Everything a load needs that takes time, made without touching the running robot:
    the scene, the task graph's run, the layout (with the plan's first moves) and the first
    decision with its certificate, and — for another scene — its connected adapter and
    planner. :meth:`Controller.install` swaps it in (quickly, on the loop's thread)."""

    scene: Scene
    graph: TaskGraph
    plan: Plan | None
    layouts: LayoutBook
    task: TaskRun
    stage: StageState  # the first decision, in ``layouts.layout``
    moves: tuple[Layout, PlannedDecision] | None  # what the plan moved for it
    adapter: Adapter | None = None  # None: the current scene stays
    planner: MotionPlanner | None = None
    warn_dropped: bool = False  # a task graph loaded without a plan: say if one is dropped
    missing_plan: str | None = None  # why a load that would take the cached plan has none

    def discard(self) -> None:
        """Not installed after all (a stop came first): disconnect the prepared adapter."""
        if self.adapter is not None:
            with contextlib.suppress(LegwsError):
                self.adapter.disconnect()
            self.adapter = None


class Controller:
    """The per-tick logic of shared autonomy (see the module docstring).

    Args:
        profile: the hardware profile.
        scene: the scene the robot works in.
        layout: the planned layout of the scene's movable objects.
        make_adapter: builds and connects the adapter for a scene.
        params: observer and certificate parameters (``dt`` and ``v_max`` from the profile).
        emit: receives the events.
        graph: the task graph to run (default: pick one of the scene's candidate goals).
        plan: stage-specific layouts of the graph (``legws plan``): at each decision the
            optimised objects go to their planned poses (the stand-in moves them; on a real
            robot a ``warning`` says where a person should put them).
        clock: monotonic clock (``legws eval`` passes its simulated one).
        operator: the person's operator model every certificate is for (``certify_with``
            of their operator file); ``None``: section 2's user.
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
        operator: OperatorModel | None = None,
    ) -> None:
        self.profile = profile
        #: the arm's description (the profile's ``arm``)
        self.arm = resolve_arm(profile.arm)
        self.params = params
        self.operator = operator
        #: the calibration under way (``None``: none was started)
        self.calibration: CalibrationRun | None = None
        self.dt = 1.0 / profile.control.rate_hz
        self.emit = emit
        self.clock = clock
        self._make_adapter = make_adapter
        self.scene = scene
        self.adapter = make_adapter(scene)
        self.planner = MotionPlanner(self.adapter.kinematics.twin(), scene.home, self.adapter.box)
        self.recovery = Recovery(self.adapter.table_height, emit)
        self.modes = ModeMachine()
        self.ticks = 0
        self.cancel = CancelDetector(self.dt)
        #: help before the commit (profile ``control.assist``; :mod:`..core.arbitration`)
        self.policy = profile.control.assist
        self.override = OverrideDetector(self.dt)
        self.handback = HandBack(self.dt)
        self._declined: str | None = None  # the blend's guess the operator overrode
        self._robot_part: FloatArray = np.zeros(3)  # the robot's share sent last tick
        self._parts: tuple[FloatArray, FloatArray] | None = None  # this tick's (operator, robot)
        self.assistant: Assistant | None = None
        self.committed: str | None = None
        self.last_state: RobotState | None = None
        self.inference = Inference(
            params, self.dt, scene.home.rotation, from_input=self.policy in ("blend", "hindsight")
        )
        self._held: Held | None = None  # what the gripper closed on, and how
        self.decisions = 0
        self._motion: FloatArray = np.zeros(3)  # the EE velocity sent last tick
        self.layouts = LayoutBook(layout, plan)
        #: the placed layout as a tracker reports it (None until one does)
        self.placement: PlacementReport | None = None
        self._placed_cache: tuple[tuple[Any, ...], tuple[float, float, int]] | None = None
        self.graph = graph if graph is not None else scene_graph(scene)
        self.task = TaskRun(self.graph, scene)
        self._place(self.layouts.layout)
        self.stage = self._begin_stage()

    @property
    def mode(self) -> Mode:
        return self.modes.mode

    @property
    def fault(self) -> str | None:
        return self.modes.fault

    @property
    def layout(self) -> Layout:
        return self.layouts.layout

    @property
    def held(self) -> Held | None:
        """What the gripper holds (``None`` while it is open or holds nothing)."""
        return self._held if self.modes.gripper != Gripper.OPEN else None

    # --- stages and inference -------------------------------------------------------
    def _begin_stage(self, prepared: StageState | None = None) -> StageState:
        """Targets of the stage(s) that come next (``prepared``: made by a load, its plan's
        moves applied); inference starts (or, with a single candidate, the commit is
        immediate)."""
        self.decisions += 1
        self._stage_tick = self.ticks  # the decision starts on this tick
        if prepared is None:
            self._apply_plan()
            prepared = StageState.of(
                self.task, self.layouts.layout, self.scene, self.params, self.operator
            )
        self.stage = prepared
        self.committed = None
        self.inference.stop()
        targets = self.stage.targets
        if self.task.finished:
            self.modes.to(Activity.IDLE)
            self.emit(TaskDone(self.graph.name, tuple(self.task.history)))
        elif len(targets) == 1 and self.policy != "none":  # without assistance: teleop
            self.modes.single_stage()
            self.modes.to(Activity.TELEOP)
            state = self._read_state_safely()
            if state is not None:
                self._commit(targets[0].name, 1.0, state, confirmed=False, single=True)
        else:
            self.modes.to(Activity.TELEOP)
            self._restart_inference()
        return self.stage

    def _apply_plan(self) -> None:
        """Move this decision's optimised objects to their planned poses."""
        if self.task.finished:
            return
        planned = self.layouts.plan_moves(self.task.label)
        if planned is None:
            return
        moves, decision = planned
        if not self._place(moves):
            self._ask_to_place(moves, decision)

    def _ask_to_place(self, moves: Layout, decision: PlannedDecision) -> None:
        """A robot that cannot move objects: where a person should put them (with the
        planned layout's certificate: the plan's, or the operator's in that layout)."""
        place = {n: {"x": p.x, "y": p.y, "yaw": p.yaw} for n, p in moves.items()}
        certificate = decision.certificate
        if self.operator is not None and certificate is not None:
            with contextlib.suppress(InputError):
                certificate = self._decision_certificate(dict(self.layouts.planned))
        self.emit(PlaceObjects(place, self.task.label, certificate))

    def _place(self, layout: Layout) -> bool:
        """Objects to ``layout`` (``False``: a person has to put them there); the planner
        plans around the layout inference uses."""
        placed = self.adapter.place_objects(layout)
        self.planner.set_layout(self.layouts.layout)
        return placed

    def _restart_inference(self) -> None:
        """A fresh observer whose start pose is where the EE is now."""
        self.committed = None
        self._declined = None
        self._robot_part = np.zeros(3)
        self.override.reset()
        self.inference.restart(self.stage, self._read_state_safely())

    def restart_task(self) -> None:
        """Start the task again from its first stage where the arm is now, objects back at
        the layout (on the stand-in), nothing in the gripper. For a simulation's restart
        (``legws eval`` puts the stand-in's arm home first); the daemon's way is a reset."""
        self.assistant = None
        self._held = None
        self.modes.forget_gripper()
        self.task = TaskRun(self.graph, self.scene)
        self._place(self.layouts.layout)
        self._begin_stage()

    def observe(self, poses: Layout, unseen: Collection[str] = ()) -> None:
        """A tracker's report on ``legws/<robot>/objects``: measured poses, and the objects
        it does not see (they keep their pose: an unseen object is never moved).

        Inference of the next decision uses the movable objects' poses; the current
        decision's certificates are recomputed from them and the placement judged
        (:meth:`check_placement`).
        """
        self.observe_all([(poses, unseen)])

    def observe_all(self, reports: Sequence[tuple[Layout, Collection[str]]]) -> None:
        """Several reports in the order they came (:meth:`observe`), judged once: only the
        layout after the last one matters."""
        now = self.clock()
        known = [
            self.layouts.observe(poses, unseen, self.scene.objects, self.scene.movable, now)
            for poses, unseen in reports
        ]
        if not any(known):
            return
        self.planner.set_layout(self.layouts.layout)
        self.check_placement(now)

    def check_placement(self, now: float | None = None) -> PlacementReport | None:
        """Judge the placed layout (:attr:`placement`) against :attr:`planned_layout` and,
        while the decision is open (nothing committed), say what to move while an object is
        misplaced or the layout is not certified (:meth:`LayoutBook.guide`); ``None`` until
        a tracker reports. Objects the task picked are not judged: the robot moved them. The
        daemon calls it at the status rate, so objects a tracker stopped reporting turn
        unseen."""
        if not self.layouts.tracking or self.task.finished:
            self.placement = None
            return None
        now = self.clock() if now is None else now
        layout = self.layouts.layout
        moved = self.task.consumed | ({self.task.held} if self.task.held else set())
        should = {n: p for n, p in self.planned_layout.items() if n not in moved}
        symmetry = {n: g.symmetry for n, g in self.scene.grasps.items()}
        objects = self.layouts.placements(now, should, symmetry)
        current = commit = certified_goals = None
        certified: bool | None = None
        if len(self.stage.targets) >= 2:
            current, commit, certified_goals = self._placed_certificates(layout)
            self.stage.observed_certificate = current
            unseen = set(self.stage.goal_names) & {o.name for o in objects if o.state == "unseen"}
            certified = current > 0 and not unseen
        report = PlacementReport(
            self.stage.name, objects, current, self.stage.certificate, commit,
            certified_goals, certified,
        )  # fmt: skip
        self.placement = report
        if self.committed is not None:
            return report  # decided: the robot is moving objects now, nothing to guide
        event = self.layouts.guide(report, self.decisions, now, self._decision_certificate)
        if event is not None:
            self.emit(event)
        return report

    @property
    def planned_layout(self) -> Layout:
        """Where every object should stand in the current decision: the plan's layout of it,
        else the daemon's layout (``--layout``) or the scene file's poses."""
        return {**self.scene.poses(), **self.layouts.planned}

    def layout_status(self) -> dict[str, Any]:
        """Status ``layout``: the scene and :attr:`planned_layout` (what a sim tracker
        renders)."""
        objects = {n: {"x": p.x, "y": p.y, "yaw": p.yaw} for n, p in self.planned_layout.items()}
        return {"scene": self.scene.name, "objects": objects}

    def _placed_certificates(self, layout: Layout) -> tuple[float, float, int]:
        """``J``, ``K`` and the commit-certified count of the decision in ``layout`` (the
        last answer kept: a tracker reports the same layout many times)."""
        key = (self.decisions, tuple(sorted(layout.items())))
        if self._placed_cache is None or self._placed_cache[0] != key:
            goals = decision_goals(self.task, layout, self.scene)
            commit = commit_for(goals, self.params, self.operator)
            slack = slack_for(goals, self.params, self.operator)
            value = (slack, commit.objective, commit.certified)
            self._placed_cache = (key, value)
        return self._placed_cache[1]

    def _decision_certificate(self, layout: Layout) -> float:
        return certificate_of(self.task, layout, self.scene, self.params, self.operator)

    def posterior(self) -> dict[str, float]:
        return self.inference.posterior()

    def live_slack(self) -> float | None:
        """The certificate seen from the current EE pose (how reliably intent can be read
        from here), or ``None`` (not teleoperating, no inference, or the EE on a goal)."""
        state = self.last_state
        if state is None or self.mode != Mode.TELEOP:
            return None
        return live_slack(self.stage, state, self.params, self.operator)

    # --- the tick -------------------------------------------------------------------------
    def _read_state_safely(self) -> RobotState | None:
        try:
            return self.adapter.read_state()
        except LegwsError:
            return None

    def tick(self, inp: OperatorInput | None) -> TickRecord:
        """Run one control period with the newest valid operator input (or ``None``)."""
        self.ticks += 1
        command: Command = zero()
        phase: str | None = None
        state: RobotState | None = None
        self._parts = None
        if self.mode != Mode.FAULT:
            try:
                state = self.adapter.read_state()
            except LegwsError as err:
                self._to_fault(f"read_state: {err}")
        if state is not None and state.stopped_by is not None and self.mode != Mode.STOPPED:
            # the robot side holds a stop the daemon did not hear (or from before it started)
            self.stop(state.stopped_by, "the robot side reports it")
        if state is not None:
            self.last_state = state
            if self.mode == Mode.TELEOP:
                self._hand_grip(state, inp)
                command = self._teleop(state, inp)
            elif self.mode == Mode.CALIBRATE:
                command = self._calibrate(state, inp)
            if self.mode == Mode.ASSIST and self.assistant is not None:
                ran = self.assistant
                command, phase = self._assist(state, inp)
                if self.mode != Mode.ASSIST or self.assistant is None:
                    phase = None  # the tick that ended it (done, cancelled, given back): its event
                elif self.assistant is not ran:
                    phase = self.assistant.phase  # the next stage's (or a fallback's) plan
        if isinstance(command, Cartesian) and self.mode in (Mode.TELEOP, Mode.CALIBRATE):
            # control came back to the operator: no jump on the way to their command
            ramped = self.handback.apply(self._motion, command.velocity)
            if ramped is not command.velocity:
                command = Cartesian(ramped, command.hold, command.floor)
        sent, joints = self._send(state, command)
        self._motion = sent
        operator, robot = self._shares(sent)
        return TickRecord(
            tick=self.ticks,
            mode=self.mode,
            state=state,
            joystick=inp.axes if inp is not None else None,
            command=sent,
            joints=joints,
            posterior=self.posterior(),
            committed=self.committed,
            phase=phase,
            sample_received=inp.received if inp is not None else None,
            sample_seq=inp.seq if inp is not None else None,
            sample_stamp=inp.stamp if inp is not None else None,
            command_sent=self.clock(),
            operator_velocity=operator,
            robot_velocity=robot,
        )

    def _shares(self, sent: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Who asked for the motion sent this tick: (operator's, robot's) velocity —
        the policy's split before the commit, scaled to what the envelope let through;
        all the robot's in ``assist``; all the operator's in teleoperation without help."""
        speed = float(np.linalg.norm(sent))
        if self.mode == Mode.ASSIST:
            return np.zeros(3), sent
        if self._parts is None or speed == 0.0:
            return sent, np.zeros(3)
        operator, robot = self._parts
        asked = float(np.linalg.norm(operator + robot))
        if asked == 0.0:
            return sent, np.zeros(3)
        scale = speed / asked  # what the envelope (and a hand-back) let through of it
        return operator * scale, robot * scale

    def _teleop(self, state: RobotState, inp: OperatorInput | None) -> Command:
        confirm = inp is not None and inp.confirm
        acts = self.policy != "none"  # without assistance the observer only infers (status)
        if self.inference.observer is None:
            # a single-candidate stage: it starts by itself, but after a failed attempt
            # only when the user confirms (no retrying for ever on its own)
            single = len(self.stage.targets) == 1
            if acts and single and (self.modes.single == SingleCommit.AUTO or confirm):
                self._commit(self.stage.targets[0].name, 1.0, state, confirmed=confirm, single=True)
                return zero()
        else:
            if inp is not None:
                self.inference.steered(inp.axes)
            commit = self.inference.update(state)
            if commit is not None and acts:
                self._commit(*commit, state, confirmed=False)
                return zero()  # assistance starts from this state
            if confirm and acts:
                # the user vouches for the object the hand is at, else the most likely goal
                self._commit(*self.inference.confirmed(state.ee_position), state, confirmed=True)
                return zero()
        if inp is None:
            self._robot_part = np.zeros(3)
            return zero()  # deadman: nothing moves, not even the orientation
        self._turn(inp)
        v_max = self.profile.control.v_max
        if self.inference.from_input:
            # the observer follows the operator's own motion, clipped as the EE's would be
            own = clamp_ee_velocity(
                self.inference.shadow, v_max * inp.axes, self.dt, self.adapter.box, v_max
            ) if self.inference.shadow is not None else np.zeros(3)  # fmt: skip
            self.inference.moved(own)
        return Cartesian(self._help(state, inp.axes), self.inference.hold)

    def _turn(self, inp: OperatorInput) -> None:
        """The rotation axes turn the orientation teleoperation holds, about the base
        frame's axes at ``w_teleop`` times the deflection (the envelope caps the turning)."""
        r = inp.rotation
        if r is None or not np.any(r):
            return
        norm = float(np.linalg.norm(r))
        angle = self.profile.control.w_teleop * min(1.0, norm) * self.dt
        self.inference.hold = axis_rotation(r / norm, angle) @ self.inference.hold

    def _hand_grip(self, state: RobotState, inp: OperatorInput | None) -> None:
        """The operator's gripper button, in teleoperation: the gripper is told what it asks
        for when that differs from what it was last told (a fault if the gripper fails);
        what it closed on is remembered as a plan's grasp is (a reset puts it back)."""
        if inp is None or inp.gripper is None:
            return
        if Gripper.of(inp.gripper) == self.modes.gripper:
            return
        try:
            self.adapter.grip(inp.gripper)
        except LegwsError as err:
            self._to_fault(f"grip: {err}")
            return
        self.modes.gripped_by_hand(inp.gripper)
        if not inp.gripper:
            self._held = None
            return
        name = self._object_at(state.ee_position)
        if name is not None:
            self._held = held_object(
                self.scene, self.layouts.layout, name, state.ee_position, state.ee_rotation,
                state.q,
            )  # fmt: skip

    def _object_at(self, position: FloatArray) -> str | None:
        """The movable object whose centre is nearest ``position`` within 6 cm (what a
        closing gripper there takes), or ``None``."""
        poses = self.scene.poses(dict(self.layouts.layout))
        best, best_d = None, 0.06
        for name in self.scene.movable:
            pose = poses[name]
            centre = np.array([pose.x, pose.y, self.scene.z_center(name)])
            d = float(np.linalg.norm(centre - position))
            if d < best_d:
                best, best_d = name, d
        return best

    def _help(self, state: RobotState, axes: FloatArray) -> FloatArray:
        """This tick's EE velocity before the commit under :attr:`policy` (the operator's
        ``v_max · u`` for ``commit``): the robot's part changes by at most the hand-back's
        acceleration bound per tick, and a ``blend`` guess held against is overridden."""
        v_max = self.profile.control.v_max
        obs = self.inference.observer
        if self.policy in ("commit", "none") or obs is None:
            return np.asarray(v_max * axes, dtype=np.float64)
        names, positions, post = obs.goals.names, obs.goals.positions, obs.posterior
        ee = state.ee_position
        if self.policy == "blend":
            speed = self.profile.control.assist_speed
            b = blend(axes, v_max, ee, positions, post, self.params.p_thresh, speed)
            if self._declined is not None and names[int(np.argmax(post))] != self._declined:
                self._declined = None  # inference guesses another goal: help toward it
            alone = Blended(v_max * axes, v_max * axes, np.zeros(3), 0.0, None)
            guess = b.guess
            if guess is None:
                self.override.reset()
            elif names[guess] == self._declined:
                b = alone
            elif self.override.update(axes, positions[guess] - ee):
                self._declined = names[guess]
                self.override.reset()
                self.handback.start()  # the operator's share grows back to all of it smoothly
                self.emit(Override(names[guess], "blend"))
                b = alone
        else:
            b = hindsight(axes, v_max, ee, positions, post, self.dt)
        # the robot's share never jumps — but a centred stick stops it at once
        robot = slew(self._robot_part, b.robot, self.handback.step) if np.any(axes) else b.robot
        self._robot_part = robot
        self._parts = (b.operator, robot)
        return np.asarray(b.operator + robot, dtype=np.float64)

    # --- calibration ---------------------------------------------------------------------
    def start_calibration(self, count: int, seed: int) -> CalibrationRun:
        """Mode ``calibrate``: ``count`` targets above the table (:mod:`.calibration`; the
        first from where the EE is), one at a time; inference stops, and loads are refused
        until the run is over.

        An assistance toward a goal under way is dropped first (the user drives again).

        Raises:
            InputError: ``count`` outside 2..200, no room for the reaches, no robot state,
                the robot stopped or in fault (reset first), or a reset on its way home.
        """
        activity = self.modes.activity
        if activity in (Activity.STOPPED, Activity.FAULT):
            raise InputError(f"the robot is in '{activity}': reset it before a calibration")
        if activity.going_home:
            raise InputError("a reset is on its way home: calibrate once it is there")
        state = self._read_state_safely()
        if state is None:
            raise InputError("the robot gives no state: no calibration without one")
        targets = targets_for(self.scene, self.adapter.box, state.ee_position, count, seed)
        self.inference.stop()
        self.inference.hold = state.ee_rotation
        self.assistant = None
        self.committed = None
        self.calibration = CalibrationRun(targets, self.dt)
        if activity == Activity.ASSIST:
            self.modes.to(Activity.TELEOP)  # the assistance dropped: the user drives again
        self.modes.to(Activity.CALIBRATE)
        return self.calibration

    def _calibrate(self, state: RobotState, inp: OperatorInput | None) -> Command:
        """One tick of a calibration: teleoperation toward the target shown (orientation
        held), the reach recorded; zero on the tick the target is reached, ``idle`` after
        the last."""
        run = self.calibration
        assert run is not None
        events, drive = run.step(self.ticks, state.ee_position, inp.axes if inp else None)
        for event in events:
            self.emit(event)
        if run.finished:
            self.modes.to(Activity.IDLE)
        if not drive or inp is None:
            return zero()  # reached (the next target appears next tick), or the deadman
        return Cartesian(self.profile.control.v_max * inp.axes, self.inference.hold)

    def _calibrating(self) -> bool:
        return self.calibration is not None and not self.calibration.finished

    def _context(self, state: RobotState) -> PlanContext:
        held = self.held
        box = self.adapter.box
        return PlanContext(state.ee_position, state.ee_rotation, state.q, self.planner, held, box)

    def _commit(
        self, goal: str, p: float, state: RobotState, *, confirmed: bool, single: bool = False
    ) -> None:
        self.modes.may_commit(single=single, confirmed=confirmed)
        t = self.stage.target(goal)
        self.committed = goal
        self.emit(
            Commit(
                goal, p, self.ticks, self.inference.seconds, self.inference.waited, t.stage,
                self.stage.name, t.action, confirmed, single, self.stage.certificate,
                self.posterior(),
            )
        )  # fmt: skip
        ctx = self._context(state)
        try:
            plan = action(t.action).plan(t, ctx)
        except InfeasibleError as err:
            self._give_back(AssistFailed(goal, "plan", str(err)))
            return
        self._start_assist([*plan, *ctx.home_after(plan)], goal, Activity.ASSIST)

    def _start_assist(self, plan: list[Primitive], target: str, activity: Activity) -> None:
        """Assistance carrying out ``plan`` for ``target`` (a goal, or :data:`RESET_LABEL`
        on a reset's way home), in ``activity``."""
        held = {self._held.name} if self._held is not None else set()
        ignore = frozenset({target, *held})  # what the arm may touch: its goal, what it holds

        def path(q0: FloatArray, q1: FloatArray) -> list[FloatArray]:
            return self.planner.joint_path(q0, q1, self.adapter.box, ignore)

        def withdraw(q0: FloatArray, q1: FloatArray) -> list[Move] | None:
            return self.planner.withdraw(q0, q1, self.adapter.box, ignore)

        speed = self.profile.control.assist_speed
        self.assistant = Assistant(
            plan, speed, self.dt, target, path, withdraw, np.array(self.arm.speed_limits)
        )
        self.cancel.reset()
        self.override.reset()
        self.handback.stop()
        self._motion = np.zeros(3)
        self.modes.to(activity)

    def _give_back(self, warning: AssistFailed) -> None:
        """Assistance cannot go on: the user drives again (a single-candidate stage then
        waits for the confirm button), inference restarts from here."""
        self.emit(warning)
        self.assistant = None
        self.modes.give_back()
        self._restart_inference()

    def _assist(self, state: RobotState, inp: OperatorInput | None) -> tuple[Command, str]:
        a = self.assistant
        assert a is not None
        button = inp is not None and inp.cancel
        going_home = self.modes.activity.going_home  # no cancel interrupts a reset
        toward_goal = self.modes.activity == Activity.ASSIST and not a.gripper_acted
        axes = inp.axes if inp else None
        if toward_goal and not button:
            # the stick held against the committed goal: an override (before the grip)
            direction = self.stage.target(a.target).position - state.ee_position
            if self.override.update(axes, direction) and inp is not None:
                self._override(a)
                # the operator's command at once, ramped from the assisted motion (tick)
                return self._teleop(state, inp), "overridden"
            reason = None
        else:
            reason = self.cancel.update(axes, self._motion, button)
        if reason is not None and not going_home:
            self._cancel(a, reason)
            return zero(), "cancelled"
        step = a.step(state.q, state.ee_position, state.ee_rotation, inp is not None)
        if step.grip is not None and Gripper.of(step.grip) != self.modes.gripper:
            try:
                self.adapter.grip(step.grip)
                self.modes.gripped(step.grip)
            except LegwsError as err:
                self._to_fault(f"grip: {err}")
                return zero(), step.phase
            self._record_grip(a, state, step.grip)
        if step.failed is not None:
            if going_home:
                ctx = self._context(state)
                plan = self.recovery.fallback(ctx, ctx.held, step.phase, step.failed)
                if plan is not None:
                    self._start_assist(plan, RESET_LABEL, self.modes.activity)
                    return zero(), step.phase
            self._give_back(AssistFailed(a.target, step.phase, step.failed))
            return zero(), step.phase
        if step.done:
            self._finish_assist(a)
            return zero(), step.phase
        if inp is None:
            return zero(), step.phase  # deadman pauses the plan
        return step.command, step.phase

    def _record_grip(self, a: Assistant, state: RobotState, closed: bool) -> None:
        """Remember what the gripper closed on, the EE pose and joint angles it took it at
        (a reset puts it back there); forget it when the gripper opens."""
        if not closed:
            self._held = None
        elif self.modes.activity == Activity.ASSIST and a.target in self.scene.movable:
            self._held = held_object(
                self.scene, self.layouts.layout, a.target, state.ee_position,
                state.ee_rotation, state.q,
            )  # fmt: skip

    def _override(self, a: Assistant) -> None:
        """The operator overrode the committed goal: the plan is dropped, control is
        theirs (the hand-back ramps from the assisted motion), inference restarts here."""
        self.assistant = None
        self.emit(Override(a.target, "assist", a.phase))
        self.modes.to(Activity.TELEOP)
        self._restart_inference()
        self.handback.start()

    def _cancel(self, a: Assistant, reason: str) -> None:
        """Give control back. Before the plan's gripper acted, the same stage's inference
        restarts from here; after it (grasped, released), the stage's effect has happened:
        the stage counts as done and the next one starts from here."""
        self.assistant = None
        self.emit(Cancel(reason, a.target, a.phase))
        self.handback.start()
        if a.gripper_acted:
            stage = self.task.advance(a.target, self.layouts.layout)
            ticks = self.ticks - self._stage_tick
            self.emit(StageDone(stage.name, a.target, stage.action, ticks, cancelled=True))
            self._begin_stage()
            if self.mode != Mode.TELEOP:
                return  # a single-candidate stage goes on by itself, or the task is done
        self.modes.to(Activity.TELEOP)
        self._restart_inference()

    def _finish_assist(self, a: Assistant) -> None:
        self.assistant = None
        if self.modes.activity.going_home:
            done = Recovered if self.modes.activity == Activity.RECOVER else Reset
            self.emit(done(self.graph.name))
            if self.calibration is not None:
                # home again: the calibration goes on (the interrupted target appears again)
                self.modes.to(Activity.CALIBRATE if self._calibrating() else Activity.IDLE)
                return
            self.task = TaskRun(self.graph, self.scene)
            self._place(self.layouts.layout)
            self._begin_stage()
            return
        stage = self.task.advance(a.target, self.layouts.layout)
        self.emit(StageDone(stage.name, a.target, stage.action, self.ticks - self._stage_tick))
        self._begin_stage()

    def _send(
        self, state: RobotState | None, command: Command
    ) -> tuple[FloatArray, FloatArray | None]:
        """Send this tick's command through the adapter's envelope; what was sent (EE
        velocity, joint velocities or ``None``). Nothing moves in ``idle``, ``stopped``
        and ``fault``; without a state the command is a halt."""
        if self.mode == Mode.FAULT or state is None:
            with contextlib.suppress(LegwsError):
                self.adapter.halt()  # if even this fails, the robot side's deadman stops it
            return np.zeros(3), None
        if self.mode in STILL:
            command = zero()
        try:
            match command:
                case Cartesian(velocity, hold, floor):
                    return self.adapter.send_velocity(state, velocity, hold, floor), None
                case Joints(qdot):
                    sent = self.adapter.send_joint_velocity(state, qdot)
                    return sent.ee_velocity, sent.qdot
                case _:
                    assert_never(command)
        except LegwsError as err:
            self._to_fault(f"send_velocity: {err}")
            return np.zeros(3), None

    def _to_fault(self, reason: str) -> None:
        first = self.modes.to_fault(reason)
        self.assistant = None
        if self.calibration is not None:
            self.calibration.interrupt()
        if first:
            self.emit(Fault(reason))
        with contextlib.suppress(LegwsError):
            self.adapter.halt()

    # --- operator commands ------------------------------------------------------------
    def stop(
        self,
        by: str,
        source: str | None = None,
        reason: str | None = None,
        *,
        announce: bool = True,
        repeats: int = 0,
    ) -> None:
        """Stop: zero velocity, the robot side told to hold the stop, mode ``stopped`` until
        the operator's ``reset``. ``by`` is the authenticated role that asked. ``announce``
        ``False``: all of that, without the ``stop`` event (a flood of stops: the daemon
        says one a second, with the ``repeats`` it did not announce)."""
        self.modes.to(Activity.STOPPED)
        self.assistant = None
        if self.calibration is not None:
            self.calibration.interrupt()
        try:
            self.adapter.stop_by(by)
        except LegwsError:
            with contextlib.suppress(LegwsError):
                self.adapter.halt()
        if announce:
            self.emit(Stop(self.mode.value, by, source, reason, repeats))

    def reset(self) -> dict[str, Any]:
        """Clear a stop or fault and start the task again: put back what the robot holds
        (or set it down: :mod:`.recovery`), go home, objects back at the layout (on the
        stand-in), infer from the first stage.

        Raises:
            HardwareError: the robot still fails.
            InfeasibleError: the robot holds an object it can set down nowhere without
                dropping it from too high (refused once; see :mod:`.recovery`).
        """
        self.adapter.resume()  # the one party that starts the robot again: the operator
        state = self._read_state_safely()
        if state is None:
            raise HardwareError(f"the robot is still failing: {self.fault or 'no state'}")
        plan = self.recovery.begin(self._context(state), self.held)
        if self.calibration is not None:
            self.calibration.interrupt()  # the reach under way is dropped (as by a stop)
        self.inference.stop()
        activity = Activity.RECOVER if self.mode == Mode.FAULT else Activity.RESET
        self._start_assist(plan, RESET_LABEL, activity)
        return {"mode": self.mode.value, "plan": [p.label for p in plan]}

    def _warn_plan_dropped(self, dropped: Plan) -> None:
        """A plan was in use and the load replaced it by none: say what that costs now."""
        planned = None
        if dropped.taskgraph == self.graph.name and not self.task.finished:
            with contextlib.suppress(LegwsError):
                planned = dropped.decision(self.task.label).certificate
                if self.operator is not None and planned is not None:
                    planned = self._decision_certificate(dropped.layout_for(self.task.label))
        self.emit(PlanDropped(dropped.taskgraph, self.stage.name, self.stage.certificate, planned))

    def prepare(
        self,
        request: CommandRequest,
        scenes: Callable[[str], Scene],
        graphs: Callable[[str], tuple[TaskGraph, Scene]],
        plans: Callable[[TaskGraph, Scene], Plan] | None = None,
    ) -> PreparedLoad:
        """The slow half of ``load_scene`` / ``load_taskgraph``: read and validate what the
        command names and build what a new scene needs. Changes nothing of the running
        controller (the daemon runs it off the control loop while the robot goes on).

        Raises:
            InputError: a calibration is under way (it ends first).
        """
        assert request.command in LOADS and request.argument is not None
        self._refuse_during_calibration()
        if request.command == "load_scene":
            return self.prepare_load(scenes(request.argument), None, None)
        graph, scene = graphs(request.argument)
        plan, missing = None, None
        if request.plan == "auto":
            if plans is None:
                raise InputError("this daemon loads no plans", field="plan")
            plan = plans(graph, scene)
        elif request.plan is None and plans is not None:
            # hands-off by default: the graph's cached plan when there is one
            try:
                plan = plans(graph, scene)
            except InputError as err:
                missing = str(err)
        same = scene.name == self.scene.name
        prepared = self.prepare_load(self.scene if same else scene, graph, plan)
        prepared.warn_dropped = True
        prepared.missing_plan = missing
        return prepared

    def prepare_load(
        self,
        scene: Scene,
        graph: TaskGraph | None,
        plan: Plan | None = None,
        layout: Layout | None = None,
    ) -> PreparedLoad:
        """A load of ``scene`` (with ``graph`` and its ``plan``; ``layout``: the scene's
        default): the task's run, the layout and the first decision certified; for another
        scene than the current one, its connected adapter and its motion planner."""
        layouts = LayoutBook(dict(layout if layout is not None else scene.default_layout()), plan)
        graph = graph if graph is not None else scene_graph(scene)
        task = TaskRun(graph, scene)
        moves = None if task.finished else layouts.plan_moves(task.label)
        stage = StageState.of(task, layouts.layout, scene, self.params, self.operator)
        prepared = PreparedLoad(scene, graph, plan, layouts, task, stage, moves)
        if scene is self.scene:
            return prepared
        adapter = self._make_adapter(scene)
        try:
            planner = MotionPlanner(adapter.kinematics.twin(), scene.home, adapter.box)
        except BaseException:
            with contextlib.suppress(LegwsError):
                adapter.disconnect()
            raise
        prepared.adapter, prepared.planner = adapter, planner
        return prepared

    def install(self, prepared: PreparedLoad) -> tuple[dict[str, Any], Adapter | None]:
        """Swap a prepared load in (the robot stops first); the task restarts. Returns the
        reply's detail and the replaced adapter, halted but still connected: the caller
        disconnects it (the daemon does so off the control loop).

        Raises:
            InputError: the load was prepared against another current scene (it reuses
                the scene in use, which has changed since).
        """
        scene = prepared.scene
        self._refuse_during_calibration()
        if prepared.adapter is None and scene is not self.scene:
            raise InputError("the scene changed while this load was prepared; send it again")
        with contextlib.suppress(LegwsError):
            self.adapter.halt()
        old = None
        dropped = self.layouts.plan if prepared.warn_dropped and prepared.plan is None else None
        if prepared.adapter is not None:
            assert prepared.planner is not None
            old, self.adapter = self.adapter, prepared.adapter
            self.scene = scene
            self.planner = prepared.planner
            self.recovery = Recovery(self.adapter.table_height, self.emit)
            prepared.adapter = None  # installed: no longer the prepared load's to discard
        self.layouts, self.graph, self.task = prepared.layouts, prepared.graph, prepared.task
        self.assistant = None
        self.modes.forget_gripper()
        placed = self._place(self.layouts.layout)
        if placed:
            self._held = None  # the stand-in let go of it and put it back
        self.recovery.drop_asked = False
        if prepared.moves is not None and not placed:
            self._ask_to_place(*prepared.moves)
        self._begin_stage(prepared.stage)
        loaded = Loaded(scene.name, self.graph.name, self.stage.name, self.stage.certificate)
        self.emit(loaded)
        if dropped is not None:
            self._warn_plan_dropped(dropped)
        if prepared.missing_plan is not None:
            self.emit(NoPlan(self.graph.name, prepared.missing_plan))
        return loaded.detail(), old

    def _refuse_during_calibration(self) -> None:
        if self._calibrating():
            raise InputError(
                "a calibration is under way: loads are refused until it ends (stop the "
                "calibration first)"
            )

    def load(
        self,
        scene: Scene,
        layout: Layout | None,
        graph: TaskGraph | None,
        plan: Plan | None = None,
    ) -> dict[str, Any]:
        """Swap to another scene or task graph (the robot stops first), with the graph's plan
        when given; the task restarts (:meth:`prepare_load` and :meth:`install` in one)."""
        return self.install_now(self.prepare_load(scene, graph, plan, layout))

    def install_now(self, prepared: PreparedLoad) -> dict[str, Any]:
        """:meth:`install`, and the replaced adapter disconnected here and now."""
        detail, old = self.install(prepared)
        if old is not None:
            old.disconnect()
        return detail

    def shutdown(self) -> None:
        """Zero velocity and disconnect (idempotent)."""
        with contextlib.suppress(LegwsError):
            self.adapter.halt()
        self.adapter.disconnect()

"""The paper's simulation protocol (method.md §8) on the deployed shared-autonomy loop.

What is measured is what runs on the robot: the daemon's
:class:`~legws_daemon.autonomy.controller.Controller` drives the ``sim`` adapter (the
MuJoCo stand-in) in simulated time — no pacing, the stand-in's cheap differential
kinematics — with the simulated user of method.md §2 on the joystick
(:class:`~legws_daemon.joystick.sim_user.SimUser`, the same as ``legws joystick
sim-user``). The protocol's definitions are kept:

- per layout every candidate's grasp is checked for IK reachability and collisions (the
  motion planner's feasibility check, whose IK solution the assistance then uses); an
  infeasible grasp leaves the candidate set, but every pick that wants it is a failure;
- pick orders are all permutations of the goals (at most :data:`MAX_ORDERS` sampled), or,
  on request, N rounds of one random order each (N picks per goal); every pick starts with
  the arm at home, the objects at the layout and inference reset;
- the user steers toward the true goal's grasp position; the observer commits at
  ``p >= p_thresh``; a user who reaches the grasp position (within
  :data:`~legws_daemon.joystick.sim_user.ARRIVED`) before any commit presses *confirm*
  (the controller then acts on the candidate the EE is at, docs/decisions.md; the observer's
  argmax then is the pick's inferred goal); a pick with neither within
  :data:`TIMEOUT_S` of motion onset is a failure.

Beyond the paper, the whole pick runs: after the commit the controller's assistance plans
and executes the approach, closes the gripper and lifts the object, then goes home. A pick
is *completed* when the true goal's object is in the gripper with its lowest point at least
:data:`LIFT_CLEARANCE` above the table; every pick that is not gets a named failure.

:func:`metrics` gives the paper's metrics, the whole pick's, and the person's of method.md
§9 (commit on the true goal per goal, wrong commits, the Kaplan–Meier median time to a
correct commit: :func:`km_sample`).
"""

from __future__ import annotations

import itertools
import math
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from legws_daemon.autonomy.controller import Controller
from legws_daemon.autonomy.events import AssistFailed, Commit, Event, Fault, Override, StageDone
from legws_daemon.autonomy.inputs import OperatorInput
from legws_daemon.autonomy.modes import Mode
from legws_daemon.core.arbitration import AssistPolicy
from legws_daemon.core.geometry import FloatArray, quat_to_matrix
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.formats.profile import ProfileSpec, load_profile_named, with_arm
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.joystick.sim_user import SimUser, UserAction, UserView
from legws_daemon.robot.feasibility import GraspCheck
from legws_daemon.scene.grasps import extents
from legws_daemon.scene.scene import Layout, Scene
from legws_daemon.sim.hand import HandUser
from legws_daemon.sim.statistics import km_median
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.runner import scene_graph

#: Most pick orders per layout (the paper samples 120 for M >= 5).
MAX_ORDERS = 120
#: A pick with neither a commit nor the user's confirmation this long after motion onset
#: fails (the paper's episode limit), seconds.
TIMEOUT_S = 30.0
#: Simulated seconds a pick may take after its commit (assistance times out per step).
ASSIST_LIMIT_S = 90.0
#: A pick is completed when the object's lowest point is this far above the table, m.
LIFT_CLEARANCE = 0.02

#: Named failures of a pick (``PickResult.failure``).
FAILURES = (
    "infeasible_grasp",  # the grasp failed the feasibility check: no episode
    "no_commit",  # neither a commit nor a confirmation within TIMEOUT_S
    "no_grasp",  # without assistance: the operator closed no gripper within TIMEOUT_S
    "wrong_commit",  # the controller acted on another goal
    "plan_failed",  # the commit's assistance could not be planned
    "assist_failed",  # a step of the assistance timed out or made no progress
    "not_lifted",  # the plan finished without the object clear of the table
    "fault",  # the adapter failed
    "limit",  # the pick ran past TIMEOUT_S + ASSIST_LIMIT_S
)

#: Called every control tick of a pick (:meth:`Evaluator.pick`'s ``on_tick``): the tick
#: from the pick's start (0, 1, ...), the EE position at the tick's start (m), the axes sent
#: to the controller, the controller's mode after the tick (what the daemon records).
TickCallback = Callable[[int, FloatArray, FloatArray, str], None]


def pick_orders(names: Sequence[str], rng: np.random.Generator) -> list[tuple[str, ...]]:
    """All permutations when there are at most :data:`MAX_ORDERS`, else that many sampled."""
    if math.factorial(len(names)) <= MAX_ORDERS:
        return list(itertools.permutations(names))
    return [tuple(names[i] for i in rng.permutation(len(names))) for _ in range(MAX_ORDERS)]


@dataclass(frozen=True, slots=True)
class PickResult:
    """One pick of an order.

    Attributes:
        true_goal: what the simulated user wanted.
        feasible: its grasp passed the feasibility check (else nothing ran).
        committed: the goal the observer committed to (``p >= p_thresh``, or a single
            candidate), or ``None``.
        commit_time: seconds from motion onset to that commit (``None`` for none, and for
            a single candidate, which needs no inference).
        confirmed: the goal the controller acted on after the user's confirmation (at the
            grasp without a commit: the candidate the hand is at), or ``None``.
        final_goal: the final inferred goal of the paper's accuracy — the commit, at a
            confirmation the observer's argmax then (which the hand's object may overrule),
            else its argmax at the end (``None`` without an episode).
        completed: the true goal's object was lifted clear of the table.
        complete_time: seconds from motion onset to completion.
        failure: one of :data:`FAILURES`, or ``None``; detail: what exactly.
        duration: simulated seconds (the whole pick, assistance and the way home included).
        decision_time: seconds of inference from motion onset to the first commit (inferred,
            confirmed, or a single candidate's: 0), else to the end of the user's steering
            (the :data:`TIMEOUT_S` limit, or a fault); the clock of ``commit_time``.
            ``None`` without an episode.
        grasp_time: seconds from motion onset to the gripper closing on an object (``None``:
            it never did); grasped: the object it closed on.
        effort: the operator's effort, the integral of the deflection ``|u| dt`` over the
            pick, seconds at full deflection.
        robot_distance, operator_distance: how far the EE moved at the robot's and at the
            operator's asking (:class:`~legws_daemon.autonomy.inputs.TickRecord`) from
            motion onset to the grasp (to the pick's end without one), m.
        overrides: the operator's overrides (:mod:`legws_daemon.autonomy.override`).
    """

    true_goal: str
    feasible: bool
    committed: str | None = None
    commit_time: float | None = None
    confirmed: str | None = None
    final_goal: str | None = None
    completed: bool = False
    complete_time: float | None = None
    failure: str | None = None
    detail: str = ""
    duration: float = 0.0
    decision_time: float | None = None
    grasp_time: float | None = None
    grasped: str | None = None
    effort: float = 0.0
    robot_distance: float = 0.0
    operator_distance: float = 0.0
    overrides: int = 0

    @property
    def robot_share(self) -> float | None:
        """The share of the approach the robot drove (``None``: nothing moved)."""
        total = self.robot_distance + self.operator_distance
        return self.robot_distance / total if total > 0 else None

    @property
    def wrong_grasp(self) -> bool:
        """The gripper closed on another object than the one wanted — or would have: a
        wrong commit ends the pick (the protocol), and its plan grasps the wrong object."""
        if self.grasped is not None:
            return self.grasped != self.true_goal
        return self.failure == "wrong_commit"

    @property
    def correct(self) -> bool:
        """Argmax accuracy of the paper: the final inferred goal is the true goal."""
        return self.final_goal == self.true_goal

    @property
    def single(self) -> bool:
        """The controller committed to the only feasible candidate, without inference."""
        return self.committed is not None and self.commit_time is None

    @property
    def commit_true(self) -> bool:
        """The controller committed to the true goal before the user arrived (an inferred
        commit, which always comes before arrival, or a single candidate's at once)."""
        return self.committed == self.true_goal


@dataclass(frozen=True, slots=True)
class LayoutEvaluation:
    """Everything measured on one layout."""

    layout: Layout
    feasibility: dict[str, GraspCheck]
    picks: list[PickResult] = field(repr=False)


def _mean(xs: Sequence[float]) -> float | None:
    return float(np.mean(xs)) if xs else None


def km_sample(picks: Sequence[PickResult]) -> tuple[list[float], list[bool]]:
    """The time to a commit on the true goal, as the person sees it, for Kaplan–Meier:
    ``(times, observed)``, one entry per pick with inference.

    - subjects: the picks that ran (an infeasible grasp has no episode) with more than one
      candidate (a single candidate is taken at once, without inference: not timed, as in
      ``t_infer_mean``);
    - event: an inferred commit (``p >= p_thresh``) on the true goal, at ``commit_time``;
    - censored at the pick's end of steering (``decision_time``; ``duration`` when not
      recorded): no commit, i.e. the user arrived and confirmed, the :data:`TIMEOUT_S`
      limit, or a fault;
    - censored at :data:`TIMEOUT_S`: a wrong commit. The person never gets the right commit
      in that pick, so it stays at risk for the whole episode window (counted against the
      median) rather than leaving the risk set early.
    """
    times: list[float] = []
    observed: list[bool] = []
    for p in picks:
        if not p.feasible or p.single:
            continue
        if p.committed is not None and p.committed != p.true_goal:
            times.append(TIMEOUT_S)
            observed.append(False)
        elif p.commit_true and p.commit_time is not None:
            times.append(p.commit_time)
            observed.append(True)
        else:
            end = p.decision_time if p.decision_time is not None else p.duration
            times.append(end)
            observed.append(False)
    return times, observed


def commit_by_goal(picks: Sequence[PickResult]) -> dict[str, float]:
    """Per true goal (sorted by name), the fraction of its picks (infeasible ones
    included) with a commit on it before arrival (:attr:`PickResult.commit_true`)."""
    hits: Counter[str] = Counter()
    total: Counter[str] = Counter()
    for p in picks:
        total[p.true_goal] += 1
        hits[p.true_goal] += p.commit_true
    return {g: hits[g] / total[g] for g in sorted(total)}


def metrics(picks: Sequence[PickResult]) -> dict[str, Any]:
    """The paper's metrics, the whole pick's, and the person's (method.md §9).

    ``accuracy`` counts a pick whose grasp is infeasible as a failure (the protocol);
    ``accuracy_feasible`` is over the picks that ran. ``commit_rate`` counts the observer's
    commits (single candidates and wrong ones included), ``confirmed_rate`` the user's
    confirmations; ``completion_rate`` is over all picks, ``completion_committed`` over the
    feasible picks the controller acted on (committed or confirmed).

    As the person sees them (every rate over all picks, infeasible ones included):
    ``commit_true_rate``, the picks with a commit on the true goal before arrival (an
    inferred commit, which always precedes arrival since arriving without one means
    confirming, or a single candidate's immediate commit); ``single_commit_rate``, the
    latter alone (subtract it for inferred commits only); ``commit_rate_by_goal`` the same
    per true goal and ``commit_rate_min_goal`` its minimum over the goals with picks;
    ``wrong_commit_rate``, commits on another goal. ``t_infer_mean`` is the paper's mean
    over the timed commits (wrong ones included); ``t_infer_km_median`` the Kaplan–Meier
    median time to a commit on the true goal (events and censoring: :func:`km_sample`),
    ``None`` when the survival never falls to one half (the median is beyond
    ``t_infer_km_max_time``) or there is no pick with inference; ``t_infer_km_picks`` and
    ``t_infer_km_events`` count its subjects and events.

    ``counts`` holds the whole numbers behind the rates, for intervals that need them (a
    Clopper–Pearson bound where every pick, or none, succeeded): ``picks`` (the denominator
    of every rate over all picks), ``commit_true``, ``wrong_commit``, ``correct``,
    ``acted_on`` and ``completed`` (those of them completed: the denominator and numerator
    of ``completion_committed``), and per true goal ``goal_picks`` and
    ``goal_commit_true`` (those of ``commit_rate_by_goal``).
    """
    n = len(picks)
    ran = [p for p in picks if p.feasible]
    times = [p.commit_time for p in picks if p.commit_time is not None]
    committed = [p for p in picks if p.committed is not None]
    wrong = [p for p in committed if p.committed != p.true_goal]
    acted = [p for p in ran if p.committed is not None or p.confirmed is not None or p.grasped]
    done = [p.complete_time for p in picks if p.complete_time is not None]
    failures = Counter(p.failure for p in picks if p.failure is not None)
    by_goal = commit_by_goal(picks)
    km_times, km_observed = km_sample(picks)
    goal_picks = Counter(p.true_goal for p in picks)
    goal_hits = Counter(p.true_goal for p in picks if p.commit_true)
    counts = {
        "picks": n,
        "commit_true": sum(p.commit_true for p in picks),
        "wrong_commit": len(wrong),
        "correct": sum(p.correct for p in picks),
        "acted_on": len(acted),
        "completed": sum(p.completed for p in acted),
        "goal_picks": {g: goal_picks[g] for g in sorted(goal_picks)},
        "goal_commit_true": {g: goal_hits[g] for g in sorted(goal_picks)},
        "grasped_true": sum(p.grasped == p.true_goal for p in picks),
        "wrong_grasps": sum(p.wrong_grasp for p in picks),
        "overrides": sum(p.overrides for p in picks),
    }
    grasps = [p.grasp_time for p in picks if p.grasp_time is not None and p.grasped == p.true_goal]
    robot = sum(p.robot_distance for p in ran)
    driven = robot + sum(p.operator_distance for p in ran)
    return {
        "episodes": n,
        "accuracy": sum(p.correct for p in picks) / n if n else None,
        "accuracy_feasible": sum(p.correct for p in ran) / len(ran) if ran else None,
        "t_infer_mean": _mean(times),
        "t_infer_sd": float(np.std(times, ddof=1)) if len(times) > 1 else None,
        "commit_rate": len(committed) / n if n else None,
        "wrong_commit_rate": len(wrong) / n if n else None,
        "no_commit_rate": (n - len(committed)) / n if n else None,
        "confirmed_rate": sum(p.confirmed is not None for p in picks) / n if n else None,
        "completion_rate": sum(p.completed for p in picks) / n if n else None,
        "completion_committed": (sum(p.completed for p in acted) / len(acted) if acted else None),
        "t_complete_mean": _mean(done),
        "infeasible_picks": sum(not p.feasible for p in picks),
        "failures": {k: failures[k] for k in FAILURES if failures[k]},
        "commit_true_rate": sum(p.commit_true for p in picks) / n if n else None,
        "single_commit_rate": sum(p.single for p in picks) / n if n else None,
        "commit_rate_by_goal": by_goal,
        "commit_rate_min_goal": min(by_goal.values()) if by_goal else None,
        "t_infer_km_median": km_median(km_times, km_observed),
        "t_infer_km_picks": len(km_times),
        "t_infer_km_events": sum(km_observed),
        "t_infer_km_max_time": max(km_times) if km_times else None,
        # the value of the assistance (time to grasp, effort, the robot's share)
        "time_to_grasp_s": _mean(grasps),
        "time_to_task_s": _mean(done),
        "effort": _mean([p.effort for p in ran]),
        "robot_share": robot / driven if driven > 0 else None,
        "wrong_grasp_rate": sum(p.wrong_grasp for p in picks) / n if n else None,
        "overrides": sum(p.overrides for p in picks),
        "completion": (sum(p.completed for p in acted) / len(acted) if acted else None),
        "counts": counts,
    }


class SimClock:
    """Simulated monotonic time: whole control periods (no rounding builds up, so a pick's
    times do not depend on how many picks ran before it)."""

    def __init__(self, dt: float) -> None:
        self.dt = dt
        self.ticks = 0

    def __call__(self) -> float:
        return self.ticks * self.dt

    def advance(self) -> None:
        self.ticks += 1


def stand_in_profile(
    params: Params, base: ProfileSpec | None = None, arm: str | None = None
) -> ProfileSpec:
    """The ``sim`` profile with the method's ``v_max`` and ``dt``, unpaced (with ``arm``:
    on that arm)."""
    p = base if base is not None else load_profile_named("sim")
    control = p.control.model_copy(update={"v_max": params.v_max, "rate_hz": 1.0 / params.dt})
    sim = p.sim.model_copy(update={"realtime": False})
    update: dict[str, object] = {"control": control, "sim": sim}
    if arm is not None:
        update["arm"] = with_arm(p, arm).arm
    return p.model_copy(update=update)


class SimStand:
    """The daemon's controller driving the MuJoCo stand-in in simulated time: the clock
    injected (ticked as fast as it computes), every event kept in :attr:`events`.

    Args:
        profile: the stand-in's profile.
        scene: the scene it starts in (its shipped layout).
        params: the model parameters.
        graph: a task graph to run (default: the scene's pick).
        operator: the person every certificate is for (method.md §10; ``None``: section
            2's user).
    """

    def __init__(
        self,
        profile: ProfileSpec,
        scene: Scene,
        params: Params,
        *,
        graph: TaskGraph | None = None,
        operator: OperatorModel | None = None,
    ) -> None:
        self.clock = SimClock(params.dt)
        self.events: list[Event] = []
        self.adapter: SimAdapter | None = None

        def make(sc: Scene) -> SimAdapter:
            adapter = SimAdapter(profile, sc, clock=self.clock)
            adapter.connect()
            self.adapter = adapter
            return adapter

        self.controller = Controller(
            profile, scene, scene.default_layout(), make, params, self.events.append,
            graph=graph, clock=self.clock, operator=operator,
        )  # fmt: skip

    @property
    def stand_in(self) -> SimAdapter:
        assert self.adapter is not None
        return self.adapter

    def close(self) -> None:
        self.controller.shutdown()


class Evaluator:
    """Runs the protocol on layouts of one scene with one controller on the stand-in.

    Args:
        scene: the scene.
        params: observer, user-model and certificate parameters.
        profile: the stand-in's profile (default: :func:`stand_in_profile`).
        operator: the simulated user steers like this operator (method.md §10, the
            robot's clip) instead of section 2's user.
        arm: the stand-in's arm (default the profile's).
        assist: the help before the commit (default the profile's, ``commit``).
    """

    def __init__(
        self,
        scene: Scene,
        params: Params | None = None,
        profile: ProfileSpec | None = None,
        *,
        operator: OperatorModel | None = None,
        arm: str | None = None,
        assist: AssistPolicy | None = None,
    ) -> None:
        self.scene = scene
        self.params = params or Params()
        self.operator = operator
        base = profile if profile is not None else stand_in_profile(self.params)
        if assist is not None:
            base = base.model_copy(
                update={"control": base.control.model_copy(update={"assist": assist})}
            )
        self.profile = with_arm(base, arm) if arm is not None else base
        self.stand = SimStand(self.profile, scene, self.params)
        self.clock = self.stand.clock
        self.events = self.stand.events
        self.controller = self.stand.controller

    @property
    def adapter(self) -> SimAdapter | None:
        return self.stand.adapter

    @property
    def stand_in(self) -> SimAdapter:
        return self.stand.stand_in

    def check(self, layout: Layout) -> dict[str, GraspCheck]:
        """Load ``layout`` (every candidate offered) and check every candidate's grasp."""
        c = self.controller
        c.load(self.scene, layout, scene_graph(self.scene))
        return {
            t.name: c.planner.check(t.name, t.position, t.rotation, t.symmetry)
            for t in c.stage.targets
        }

    def prepare(self, layout: Layout) -> dict[str, GraspCheck]:
        """Check every candidate's grasp in ``layout``, then load it with the feasible ones
        as the candidates (what :meth:`pick` then runs on); returns the checks."""
        checks = self.check(layout)
        feasible = [n for n in self.scene.goal_names if checks[n].feasible]
        self.controller.load(self.scene, layout, scene_graph(self.scene, feasible))
        return checks

    def evaluate(
        self, layout: Layout, seed: int | Sequence[int], episodes_per_goal: int | None = None
    ) -> LayoutEvaluation:
        """Every pick order of ``layout`` (:func:`pick_orders`), or with
        ``episodes_per_goal`` N rounds each picking every goal once in a random order (N
        picks per goal); seeded, so the same seed gives the same picks. Every pick starts
        from home with the objects at the layout and inference reset."""
        rng = np.random.default_rng(seed)
        checks = self.prepare(layout)
        feasible = [n for n in self.scene.goal_names if checks[n].feasible]
        picks: list[PickResult] = []
        names = list(self.scene.goal_names)
        if episodes_per_goal is None:
            orders = pick_orders(names, rng)
        else:
            if episodes_per_goal < 1:
                raise InputError(f"episodes_per_goal must be >= 1, got {episodes_per_goal}")
            orders = [
                tuple(names[i] for i in rng.permutation(len(names)))
                for _ in range(episodes_per_goal)
            ]
        for order in orders:
            for name in order:
                if name in feasible:
                    picks.append(self.pick(name, rng))
                else:
                    picks.append(PickResult(name, False, failure="infeasible_grasp",
                                            detail=checks[name].reason))  # fmt: skip
        return LayoutEvaluation(dict(layout), checks, picks)

    def _lifted(self, goal: str) -> bool:
        """The object ``goal`` is in the gripper, its lowest point clear of the table."""
        a = self.stand_in
        if a.held != goal:
            return False
        position, quaternion = a.kinematics.object_pose(goal)
        o = self.scene.objects[goal]
        ext = np.array(extents(o.shape, tuple(o.size)))
        half = 0.5 * float(np.abs(quat_to_matrix(quaternion)[2]) @ ext)
        return float(position[2]) - half >= self.scene.workspace.table_height + LIFT_CLEARANCE

    def pick(
        self,
        goal: str,
        rng: np.random.Generator,
        onset: float = 0.0,
        on_tick: TickCallback | None = None,
    ) -> PickResult:
        """One pick of ``goal`` from home, as the protocol says (see the module docstring).

        ``onset``: the user hesitates this many seconds before the first push (the stick
        held still, as a person who has just been told the goal); every time of the result
        counts from the pick's start, so it includes the hesitation, and the limits count
        from the motion's onset. ``on_tick``: called every control tick
        (:data:`TickCallback`); it changes nothing of the pick."""
        c, a, clock = self.controller, self.stand_in, self.clock
        first = len(self.events)  # a single candidate is committed to by the restart
        a.reset_arm()
        c.restart_task()
        user = SimUser(
            [goal], self.params.sigma, self.params.v_max, rng, operator=self.operator,
            dt=self.params.dt,
        )  # fmt: skip
        # without assistance the operator finishes the pick by hand (nothing commits)
        by_hand = self.profile.control.assist == "none"
        hand = HandUser(user, c.stage.target(goal), a.box) if by_hand else None
        start = clock.ticks
        committed = confirmed = inferred = failure = None
        commit_time = complete_time = decision_time = None
        detail = ""
        completed = False
        targets: dict[str, np.ndarray] = {}
        stage = None
        grasp_time: float | None = None
        grasped: str | None = None
        effort = robot_distance = operator_distance = 0.0
        overrides = 0
        while True:
            now = (clock.ticks - start) * clock.dt
            if c.mode == Mode.IDLE or failure is not None:
                break
            moving = now - onset  # seconds since the motion's onset
            acted = committed is not None or confirmed is not None or grasped is not None
            if not acted and moving >= TIMEOUT_S:
                if by_hand:
                    failure, detail = "no_grasp", f"no grasp within {TIMEOUT_S:g} s"
                else:
                    failure, detail = "no_commit", f"no commit within {TIMEOUT_S:g} s"
                break
            if by_hand and completed:
                break  # lifted by hand: the pick is done (no plan takes it home)
            if moving >= TIMEOUT_S + ASSIST_LIMIT_S:
                failure, detail = "limit", f"still in '{c.mode}' after {now:.0f} s"
                break
            if c.stage is not stage:
                stage = c.stage
                targets = {t.name: t.position for t in stage.targets}
            here = a.kinematics.ee_position()
            if moving < 0:
                act = UserAction(np.zeros(3))  # hesitating: the stick held still
            elif hand is not None:
                act = hand.act(here, a.kinematics.ee_rotation(), now)
            else:
                view = UserView(c.mode.value, c.decisions, c.stage.name, here, targets)
                act = user.act(view, now)
            rec = c.tick(
                OperatorInput(act.axes, act.confirm, act.cancel, clock(),
                              rotation=act.rotation, gripper=act.gripper)
            )  # fmt: skip
            if on_tick is not None:
                on_tick(clock.ticks - start, here, act.axes, rec.mode.value)
            clock.advance()
            effort += float(np.linalg.norm(act.axes)) * clock.dt
            if grasped is None:
                if rec.robot_velocity is not None:
                    robot_distance += float(np.linalg.norm(rec.robot_velocity)) * clock.dt
                if rec.operator_velocity is not None:
                    operator_distance += float(np.linalg.norm(rec.operator_velocity)) * clock.dt
                if a.held is not None:
                    grasped, grasp_time = a.held, (clock.ticks - start) * clock.dt
            for event in self.events[first:]:
                match event:
                    case Commit():
                        if decision_time is None:
                            decision_time = event.seconds
                        if event.confirmed:
                            confirmed = event.goal
                            if event.posterior:  # what the observer said when confirmed
                                inferred = max(event.posterior, key=event.posterior.__getitem__)
                        else:
                            committed = event.goal
                            if not event.single:
                                commit_time = event.seconds
                        if event.goal != goal:
                            failure, detail = "wrong_commit", f"acted on '{event.goal}'"
                    case AssistFailed():
                        failure = "plan_failed" if event.phase == "plan" else "assist_failed"
                        detail = f"{event.phase}: {event.error}"
                    case Fault():
                        failure, detail = "fault", event.error
                    case Override():
                        overrides += 1
                    case StageDone() if not completed:
                        failure, detail = "not_lifted", f"'{goal}' was not lifted clear"
                    case _:
                        pass
            first = len(self.events)
            if not completed and self._lifted(goal):
                completed, complete_time = True, (clock.ticks - start) * clock.dt
        final = committed or inferred or confirmed
        if final is None and c.inference.observer is not None:
            final = c.inference.most_likely()[0]
        self.events.clear()
        duration = (clock.ticks - start) * clock.dt
        if decision_time is None:  # no commit: the user steered until the pick ended
            decision_time = duration
        return PickResult(
            goal, True, committed, commit_time, confirmed, final, completed, complete_time,
            failure, detail, duration, decision_time, grasp_time, grasped, effort,
            robot_distance, operator_distance, overrides,
        )  # fmt: skip

"""Stage-specific layouts (method.md §5, §7): one layout per decision point of a task graph.

For each decision point (:func:`~legws_daemon.task.decisions.decision_points`), in the
order a run meets them, starting from the layout of the decision it is reached from (the
first from the scene file's layout):

* one candidate: nothing to infer; the layout is kept and its target checked;
* the *optimised* objects are the candidates that are movable objects of the scene, not
  fixed by the graph and not ``return`` goals; their ``(x, y, yaw)`` are searched
  (:func:`~legws_daemon.design.search.search` on a :class:`LayoutProblem` whose goals are
  the decision's targets, :class:`~legws_daemon.design.stage_goals.TargetGoals`) to
  maximise the certificate ``J`` of every candidate's target from the EE home, with the
  constraints, penalties and reachability screen of ``legws optimize``; every other
  object stays put and counts as an obstacle;
* no optimised object (only places or fixed objects): certified, not optimised.

The chosen layout is the best elite, of those that beat the starting layout, that meets
every constraint and whose targets all pass the full IK and collision check (the
starting layout when none does and it passes itself), so ``J`` never drops below the
start's when the start is feasible. When nothing passes, the plan says so
(``feasible: false`` and a note) and keeps the best layout that meets the constraints.

Plans are cached in ``$XDG_CACHE_HOME/legws/plan/<key>/`` (``plan.json`` and one top-view
picture per decision), keyed by the task-graph file, the scene file, the robot model and
the settings; a folder is written completely under a temporary name, then renamed. A
cached plan is used only when it validates, its stage layouts and certificates included
(:func:`~legws_daemon.task.plan_file.check_plan`: the checks of a ``--layout`` file, and
the certificates the layouts give); one that does not is logged, planned again and replaced.
"""

from __future__ import annotations

import logging
import shutil
import tempfile
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from legws_daemon import __version__
from legws_daemon.arms import DEFAULT_ARM
from legws_daemon.core.certificate import certify
from legws_daemon.core.commit import (
    CommitCertificate,
    certify_commit,
    commit_rate_estimate,
    commit_time_estimate,
)
from legws_daemon.core.geometry import FloatArray
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.params import Params
from legws_daemon.design import METHODS, OBJECTIVES
from legws_daemon.design.operators import design_for, operator_settings, worst_score
from legws_daemon.design.optimize import check_capacity
from legws_daemon.design.plan_cache import (
    PLAN_FILE,
    copy_out,
    load_cached,
    plan_cache_dir,
    plan_key,
    publish,
    read_cached,
)
from legws_daemon.design.problem import LayoutProblem
from legws_daemon.design.stage_goals import TargetGoals
from legws_daemon.errors import InfeasibleError, InputError, LegwsError
from legws_daemon.formats.files import write_atomic
from legws_daemon.formats.operator_file import OperatorFile
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.planner import MotionPlanner, stand_in_planner
from legws_daemon.robot.reachability import ReachabilityMap, load_or_build
from legws_daemon.robot.world import World
from legws_daemon.scene.scene import Layout, Scene
from legws_daemon.task.actions import action, target
from legws_daemon.task.decisions import DecisionPoint, decision_points
from legws_daemon.task.graph import TaskGraph
from legws_daemon.task.plan import DEFAULT_ITERATIONS, Plan, PlannedDecision, image_name
from legws_daemon.task.plan_file import dump_plan
from legws_daemon.task.targets import Target, goal_set

if TYPE_CHECKING:  # the search (pyribs, numba) is imported only when a decision is searched
    from legws_daemon.design.search import SearchResult

#: Elites tried, best first, before the plan gives up on a decision's full check.
MAX_VERIFIED = 30

log = logging.getLogger("legws.plan")


def decision_targets(scene: Scene, point: DecisionPoint, layout: Layout) -> list[Target]:
    """The targets of a decision's candidates in ``layout`` (each by its stage's action)."""
    stage = point.stage_of
    return [target(scene, layout, stage[c], action, c) for c, action in point.actions.items()]


@dataclass
class _Planner:
    """What every decision of one planning run shares."""

    graph: TaskGraph
    scene: Scene
    params: Params
    method: str
    iterations: int
    seed: int
    progress: bool
    objective: str
    commit_form: str
    world: World
    q_home: FloatArray
    operators: tuple[OperatorFile, ...] = ()
    _screen: ReachabilityMap | None = None
    _motion: MotionPlanner | None = None
    _models: tuple[Any, ...] = field(default=(), repr=False)

    def __post_init__(self) -> None:
        self._models = tuple(f.certify_with for f in self.operators)

    @property
    def screen(self) -> ReachabilityMap:
        if self._screen is None:
            self._screen = load_or_build(self.world, self.q_home)
        return self._screen

    def targets(self, point: DecisionPoint, layout: Layout) -> list[Target]:
        return decision_targets(self.scene, point, layout)

    def goals(self, point: DecisionPoint, layout: Layout) -> GoalSet:
        """The decision's targets in ``layout`` as a goal set from the EE home."""
        return goal_set(self.targets(point, layout), self.scene.home)

    def certificate(self, point: DecisionPoint, layout: Layout) -> float:
        return certify(self.goals(point, layout), self.params).objective

    def commit(self, point: DecisionPoint, layout: Layout, form: str = "min") -> CommitCertificate:
        return certify_commit(self.goals(point, layout), self.params, form=form)

    def rate(self, point: DecisionPoint, layout: Layout) -> float:
        return commit_rate_estimate(self.goals(point, layout), self.params)

    def score(self, point: DecisionPoint, layout: Layout) -> float:
        """What the search maximises: J, -K (of the design's commit form), R or -T (for the
        operators designed for, the worst of theirs)."""
        if self._models:
            return worst_score(
                self.objective, self.goals(point, layout), self.params, self._models,
                self.commit_form,
            )  # fmt: skip
        if self.objective == "commit":
            return -self.commit(point, layout, self.commit_form).objective
        if self.objective == "rate":
            return self.rate(point, layout)
        if self.objective == "time":
            return -commit_time_estimate(self.goals(point, layout), self.params)
        return self.certificate(point, layout)

    def check(
        self, point: DecisionPoint, layout: Layout, moving: Collection[str] = ()
    ) -> tuple[Target, str] | None:
        """``None`` when every target passes the motion planner's check (IK, collisions, a
        straight approach, a clear way from home), else the first target that does not
        and why. The targets that do not move (not in ``moving``) are checked first: one of
        them out of reach is out of reach in every layout, and the search stops there."""
        if self._motion is None:
            self._motion = stand_in_planner(self.world)
        return first_infeasible(self._motion, self.scene, point, layout, moving)


def first_infeasible(
    motion: MotionPlanner,
    scene: Scene,
    point: DecisionPoint,
    layout: Layout,
    moving: Collection[str] = (),
) -> tuple[Target, str] | None:
    """The first target of decision ``point`` in ``layout`` that fails ``motion``'s check
    (IK, collisions, a straight approach, a clear way from home) and why; ``None`` when all
    pass. The targets not in ``moving`` are checked first."""
    motion.set_layout(scene.poses(layout))
    targets = sorted(decision_targets(scene, point, layout), key=lambda t: t.name in moving)
    for t in targets:
        found = motion.check(t.name, t.position, t.rotation, t.symmetry)
        if not found.feasible:
            return t, found.reason
    return None


def _optimised(graph: TaskGraph, scene: Scene, point: DecisionPoint) -> tuple[str, ...]:
    return tuple(
        c
        for c, name in point.actions.items()
        if c in scene.movable and c not in graph.fixed and action(name).follows_layout
    )


def _why(failure: tuple[Target, str] | None) -> str | None:
    return None if failure is None else f"{failure[0].name} ({failure[0].action}): {failure[1]}"


def _plan_decision(p: _Planner, index: int, point: DecisionPoint, base: Layout) -> PlannedDecision:
    names = _optimised(p.graph, p.scene, point)
    shell = PlannedDecision(
        label=point.label,
        stages=tuple(s.name for s in point.stages),
        candidates=point.candidates,
        actions=point.actions,
        inference=point.inference,
        optimised=(),
        layout=dict(base),
        certificate=None,
        certificate_start=None,
        feasible=False,
        image=None,
    )
    start_problem = _why(p.check(point, base))
    if not point.inference or not names:
        note = (
            "no inference needed (one candidate)"
            if not point.inference
            else "certified, not optimised: no candidate is a movable object to place"
        )
        j = p.certificate(point, base) if point.inference else None
        k = p.commit(point, base) if point.inference else None
        return replace(
            shell,
            certificate=j,
            certificate_start=j,
            commit_objective=k.objective if k else None,
            commit_certified=k.certified if k else None,
            commit_rate_estimate=p.rate(point, base) if point.inference else None,
            feasible=start_problem is None,
            note=note if start_problem is None else f"{note}; {start_problem}",
        )
    j_start = p.certificate(point, base)
    k_start = p.commit(point, base)
    score_start = p.score(point, base)
    layout, problem = _search(p, index, point, base, names, score_start, start_problem is None)
    r_start = p.rate(point, base)
    j = p.certificate(point, layout)
    k = p.commit(point, layout)
    r = p.rate(point, layout)
    if problem is None:
        note = (
            f"optimised {', '.join(names)}: J {j_start:.3f} -> {j:.3f}, "
            f"K {k_start.objective:.3f} -> {k.objective:.3f}, R {r_start:.2f} -> {r:.2f}"
        )
        if p.operators:  # the numbers are section 2's user's; the search was the people's
            note += f" (designed for {design_for([f.name for f in p.operators])})"
    else:
        note = f"no layout passed the full check: {problem}"
    return replace(
        shell,
        optimised=names,
        layout=layout,
        certificate=j,
        certificate_start=j_start,
        commit_objective=k.objective,
        commit_certified=k.certified,
        commit_rate_estimate=r,
        feasible=problem is None,
        note=note,
    )


def _search(
    p: _Planner,
    index: int,
    point: DecisionPoint,
    base: Layout,
    names: tuple[str, ...],
    score_start: float,
    start_ok: bool,
) -> tuple[Layout, str | None]:
    """The chosen layout of every movable object and ``None``, or the fallback and why."""
    goals = TargetGoals(p.scene, point, names, base)
    problem = LayoutProblem(
        p.scene, names, p.params, p.screen, goals=goals, base=base, objective=p.objective,
        commit_form=p.commit_form, operators=p._models,
    )  # fmt: skip
    check_capacity(problem)
    result = _run_search(p, problem, point.label, p.seed + index)
    fallback: Layout | None = None
    first_problem: str | None = None
    for elite, row in list(zip(result.elites, result.table, strict=True))[:MAX_VERIFIED]:
        score = row["score"]
        if start_ok and score <= score_start:
            continue  # cannot beat the start, which passes
        layout = {**base, **problem.layout(elite.solution)}
        if problem.constraints.problems(p.scene.poses(layout)):
            continue
        fallback = fallback or layout
        failure = p.check(point, layout, names)
        if failure is None:
            return layout, None
        first_problem = first_problem or _why(failure)
        if failure[0].name not in names and failure[1].startswith("out of reach"):
            break  # a target that does not move is out of reach in every layout
    if start_ok:
        return dict(base), None
    return (fallback or dict(base)), (first_problem or "no elite met the layout constraints")


def search(
    problem: LayoutProblem,
    method: str = "cma-me",
    iterations: int = 1000,
    seed: int = 0,
    progress: Callable[[int, float, float], None] | None = None,
) -> SearchResult:
    """:func:`legws_daemon.design.search.search`, imported when a decision is searched: a
    cached plan (the daemon's ``cached_plan``) loads neither pyribs nor numba."""
    from legws_daemon.design.search import search as run

    return run(problem, method, iterations, seed, progress)


def _run_search(p: _Planner, problem: LayoutProblem, label: str, seed: int) -> SearchResult:
    if not p.progress:
        return search(problem, p.method, p.iterations, seed)
    from tqdm import tqdm

    with tqdm(total=p.iterations, desc=label, unit="it", leave=False) as bar:

        def tick(_it: int, _best: float, _coverage: float) -> None:
            bar.update(1)

        return search(problem, p.method, p.iterations, seed, tick)


def _plan(p: _Planner) -> list[tuple[DecisionPoint, PlannedDecision]]:
    planned: list[tuple[DecisionPoint, PlannedDecision]] = []
    for i, point in enumerate(decision_points(p.graph)):
        base = p.scene.default_layout() if point.parent is None else planned[point.parent][1].layout
        planned.append((point, _plan_decision(p, i, point, base)))
    return planned


def _render(
    p: _Planner, planned: list[tuple[DecisionPoint, PlannedDecision]], folder: Path
) -> list[PlannedDecision]:
    """Write one picture per decision into ``folder``; without GL, a warning and no images."""
    from legws_daemon.design.plan_render import decision_picture

    out: list[PlannedDecision] = []
    for point, d in planned:
        j = "" if d.certificate is None else f"  J = {d.certificate:.3f}"
        title = f"{p.graph.name}: {d.label}{j}"
        try:
            png = decision_picture(
                p.scene, d.layout, p.targets(point, d.layout), title, arm=p.world.spec.name
            )
        except LegwsError as err:  # no GL here: the plan still stands
            log.warning("legws: warning: no pictures of the plan: %s", err)
            return [d for _, d in planned]
        write_atomic(folder / image_name(d.label), png)
        out.append(replace(d, image=image_name(d.label)))
    return out


def plan_settings(
    method: str = "cma-me",
    iterations: int = DEFAULT_ITERATIONS,
    seed: int = 0,
    objective: str = "slack",
    commit_form: str = "sum",
    params: Params | None = None,
    operators: Sequence[OperatorFile] = (),
    arm: str = DEFAULT_ARM,
) -> dict[str, Any]:
    """The settings a plan's cache key is made of (``plan.json``'s ``settings``): with
    ``operators`` also each person's ``name`` and ``model`` and ``design_for``; for an arm
    other than the default, its name (``arm``)."""
    settings: dict[str, Any] = {
        "method": method,
        "iterations": iterations,
        "seed": seed,
        "params": (params or Params()).as_dict(),
        "version": __version__,
    }
    if objective != "slack":  # absent means slack: plans made before the option keep their key
        settings["objective"] = objective
        settings["commit_form"] = commit_form
    if operators:  # absent means section 2's user (the key of plans made before the option)
        settings["operators"] = operator_settings(operators)
        settings["design_for"] = design_for([f.name for f in operators])
    if arm != DEFAULT_ARM:  # absent means the Sawyer (the key of plans made before arms)
        settings["arm"] = arm
    return settings


def cached_plan(
    graph: TaskGraph,
    scene: Scene,
    operators: Sequence[OperatorFile] = (),
    arm: str = DEFAULT_ARM,
) -> Plan | None:
    """The graph's plan with the default settings (``legws plan NAME``, with ``operators``:
    ``--operator``) from the cache, or ``None`` (nothing is planned: for the daemon's
    ``load_taskgraph``, on the loop).

    Raises:
        InputError: the cached plan does not validate (as in
            :func:`~legws_daemon.design.plan_cache.load_cached`, stage layouts and
            certificates included); the message says what is wrong and to plan it again
            with ``legws plan NAME``.
    """
    folder = plan_cache_dir() / plan_key(graph, scene, plan_settings(operators=operators, arm=arm))
    plan, problem = read_cached(folder, graph, scene)
    if problem is not None:
        raise InputError(
            f"the cached plan of task graph '{graph.name}' is not usable ({problem}); plan it "
            f"again with `legws plan {graph.name}` (the daemon does not plan on its control "
            "loop)",
            field="plan",
        )
    return plan


def plan_taskgraph(
    graph: TaskGraph,
    scene: Scene,
    *,
    method: str = "cma-me",
    iterations: int = DEFAULT_ITERATIONS,
    seed: int = 0,
    objective: str = "slack",
    commit_form: str = "sum",
    params: Params | None = None,
    operators: Sequence[OperatorFile] = (),
    arm: str = DEFAULT_ARM,
    progress: bool = False,
    use_cache: bool = True,
    out_dir: Path | None = None,
    render: bool = True,
) -> Plan:
    """Plan a layout for every decision point of ``graph`` (see the module's docstring).

    Args:
        graph: the task graph (its ``source`` file is part of the cache key).
        scene: its scene.
        method, iterations, seed: the search's settings (per optimised decision).
        objective: ``slack`` (maximise J) or ``commit`` (minimise K, method.md §9).
        commit_form: with ``commit``, the commit slack's form (``core.commit``); plan.json
            records section 9's K (``min``) either way.
        params: model parameters of the certificate (default: the method's).
        operators: design every decision for these people (the worst of them, method.md
            §10, the robot's clip); plan.json's ``settings`` records them. The recorded
            certificates stay section 2's user's.
        arm: the arm the layouts are for (reach, grasps and motions are its own).
        progress: a progress bar per search on stderr.
        use_cache: load the plan from the cache when there, and store it there.
        out_dir: also copy ``plan.json`` and the pictures into this folder.
        render: draw a top view of each decision's layout (needs OpenGL; without a cache
            or ``out_dir`` there is nowhere to keep pictures, so none are drawn).

    Returns:
        The plan; its ``directory`` holds ``plan.json`` and the pictures (``out_dir``,
        else the cache folder, else ``None``).
    """
    if method not in METHODS:
        raise InputError(
            f"unknown method '{method}'; known: {', '.join(METHODS)}", field="--method"
        )
    if iterations < 1:
        raise InputError(f"expected at least 1 iteration, got {iterations}", field="--iterations")
    if objective not in OBJECTIVES:
        raise InputError(
            f"unknown objective '{objective}'; known: {', '.join(OBJECTIVES)}",
            field="--objective",
        )
    params = params or Params()
    settings = plan_settings(
        method, iterations, seed, objective, commit_form, params, operators, arm
    )
    key = plan_key(graph, scene, settings)
    folder = plan_cache_dir() / key
    cached = load_cached(folder, graph, scene) if use_cache else None
    if cached is not None:
        return copy_out(cached, out_dir) if out_dir is not None else cached
    started = time.perf_counter()
    world = World(scene, arm=arm)
    q_home = home_configuration(world, scene.home.position, scene.home.rotation).q
    planner = _Planner(
        graph,
        scene,
        params,
        method,
        iterations,
        seed,
        progress,
        objective,
        commit_form,
        world,
        np.asarray(q_home, dtype=np.float64),
        tuple(operators),
    )
    planned = _plan(planner)
    decisions = [d for _, d in planned]
    keep = use_cache or out_dir is not None
    root = plan_cache_dir() if use_cache else None
    if root is not None:
        root.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{key}.", dir=root))
    try:
        if render and keep:
            decisions = _render(planner, planned, staging)
        plan = Plan(
            graph.name,
            scene.name,
            key,
            settings,
            tuple(decisions),
            time.perf_counter() - started,
            directory=staging,
        )
        write_atomic(staging / PLAN_FILE, dump_plan(plan))
        if use_cache:
            publish(staging, folder)
            plan = replace(plan, directory=folder)
        if out_dir is not None:
            plan = copy_out(plan, out_dir)
        elif not use_cache:
            plan = replace(plan, directory=None)
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
    return plan


def random_feasible_layout(
    graph: TaskGraph,
    scene: Scene,
    seed: int,
    *,
    arm: str = DEFAULT_ARM,
    tries: int = 200,
) -> Layout:
    """A random layout of the graph's movable candidates (those it does not fix) that meets
    the scene's constraints and in which every decision's every target passes the motion
    planner's check (the layout a ``random`` condition of a study runs the whole graph in);
    the first of ``tries`` seeded draws that does.

    Raises:
        InfeasibleError: none of the draws is feasible.
    """
    points = decision_points(graph)
    names = tuple(
        dict.fromkeys(
            c
            for point in points
            for c in point.candidates
            if c in scene.movable and c not in graph.fixed
        )
    )
    base = scene.default_layout()
    if not names:
        return base
    from legws_daemon.scene.constraints import LayoutConstraints

    cons = LayoutConstraints.of(scene, names)
    rows = cons.sample(tries, np.random.default_rng([seed, 0x57D1]))
    motion = stand_in_planner(World(scene, arm=arm))
    for row in rows:
        layout = {**base, **cons.to_layout(row)}
        if all(first_infeasible(motion, scene, p, layout) is None for p in points):
            return layout
    raise InfeasibleError(
        f"no feasible random layout of '{graph.name}' in {tries} draws (seed {seed})"
    )

"""``legws eval``: the protocol over many layouts, on a process pool, with a report.

Each layout's episodes are seeded from ``(seed, layout index)``, so the numbers do not
depend on how layouts are spread over the workers: same seed, same result. The report holds
the paper's metrics and the person's (method.md §9) with 95 % bootstrap intervals over
layouts and, for optimised layouts from several runs (seeds), over runs.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, RootModel, Strict, StrictBool

from legws_daemon.arms import DEFAULT_ARM
from legws_daemon.core.arbitration import AssistPolicy
from legws_daemon.core.geometry import FloatArray
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError
from legws_daemon.formats.validation import (
    Finite,
    nested,
    read_json,
    read_json_with_lines,
    validate,
)
from legws_daemon.robot.assets import arm_dir
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import LayoutConstraints, require_feasible
from legws_daemon.scene.layout_file import layout_from_data, layout_to_data, load_layout
from legws_daemon.scene.scene import Layout, Scene
from legws_daemon.sim.protocol import Evaluator, PickResult, km_sample, metrics
from legws_daemon.sim.statistics import (
    LEVEL,
    RESAMPLES,
    RateInterval,
    km_counts,
    km_median_counts,
    percentile_interval,
    rate_interval,
    ratio_interval,
    resample_counts,
)
from legws_daemon.workers import worker_context

_worker: Evaluator | None = None

#: Bootstrap interval keys: the person's metrics and the paper's (method.md §9).
INTERVAL_KEYS = (
    "commit_true_rate",
    "commit_rate_min_goal",
    "wrong_commit_rate",
    "accuracy",
    "completion_committed",
    "t_infer_mean",
    "t_infer_km_median",
)


def _init_worker(
    scene_source: str,
    params: Params,
    operator: OperatorModel | None = None,
    arm: str = DEFAULT_ARM,
    assist: AssistPolicy = "commit",
) -> None:
    global _worker
    _worker = Evaluator(load_scene(scene_source), params, operator=operator, arm=arm, assist=assist)


Job = tuple[int, Layout, int, int | None]


def _evaluate(job: Job) -> tuple[int, dict[str, Any], list[PickResult]]:
    index, layout, seed, episodes_per_goal = job
    assert _worker is not None
    ev = _worker.evaluate(layout, [seed, index], episodes_per_goal)
    infeasible = {n: c.reason for n, c in ev.feasibility.items() if not c.feasible}
    return index, {"infeasible": infeasible}, ev.picks


def random_layouts(scene: Scene, n: int, seed: int) -> list[Layout]:
    """``n`` random layouts of the scene's candidate goals satisfying the constraints."""
    cons = LayoutConstraints.of(scene, scene.goal_names)
    poses = cons.sample(n, np.random.default_rng([seed, 0x1A70]))
    return [cons.to_layout(row) for row in poses]


# --- optimised layouts: the verified elites of `legws optimize` run folders ---------------


@dataclass(frozen=True, slots=True)
class Elite:
    """Where an evaluated layout comes from.

    Attributes:
        run: the optimisation run folder.
        rank: its rank among the run's elites (``elites.json``'s ``rank``; for
            ``best_layout.json``, ``summary.json``'s ``verified_rank``, else ``None``).
        position: 1 for the run's best verified elite, 2 for the next, ...
        objective: its objective as the run reported it, or ``None``.
    """

    run: str
    rank: int | None
    position: int
    objective: float | None


class _EliteEntry(BaseModel):
    model_config = ConfigDict(extra="ignore")

    rank: Annotated[int, Strict(), Field(ge=0)]
    layout: dict[str, Any]
    objective: Finite | None = None
    verified: StrictBool


class _ElitesFile(RootModel[list[_EliteEntry]]):
    pass


def load_elites(run_dir: Path, scene: Scene, k: int) -> list[tuple[Layout, Elite]]:
    """The ``k`` best verified elites of an optimisation run folder, best first.

    Reads ``RUN_DIR/elites.json`` (a list, best first, of ``{"rank", "layout",
    "objective", "verified"}``); without it, ``k = 1`` takes ``best_layout.json`` (the run's
    best verified elite). Every layout must satisfy the scene's constraints. Errors
    (missing files, fewer than ``k`` verified elites, a bad layout) are
    :class:`InputError` naming the file, and the line and field of each error of it.
    """
    if k < 1:
        raise InputError(f"expected K >= 1, got {k}", field="--top-k")
    path = run_dir / "elites.json"
    if os.path.lexists(path):  # a device or FIFO in its place is refused by the reader
        data, where = read_json_with_lines(path, "elites")
        entries = validate(_ElitesFile, data, str(path), where).root
        verified = [(i, e) for i, e in enumerate(entries) if e.verified]
        if len(verified) < k:
            raise InputError(
                f"{len(verified)} verified elites, --top-k asks for {k}", source=str(path)
            )
        out = []
        for position, (i, e) in enumerate(verified[:k], start=1):
            try:
                layout = layout_from_data(e.layout, scene, str(path))
            except InputError as err:  # each error at its line in the entry's layout
                raise nested(err, str(path), (i, "layout"), where) from None
            source = f"{where.at(str(path), (i, 'layout'))}: [{i}].layout"
            layout = require_feasible(scene, layout, source)
            out.append((layout, Elite(str(run_dir), e.rank, position, e.objective)))
        return out
    best = run_dir / "best_layout.json"
    if k > 1 or not os.path.lexists(best):
        raise InputError(
            f"no elites.json (needed for --top-k {k})"
            if k > 1
            else "not an optimisation run folder (neither elites.json nor best_layout.json)",
            source=str(run_dir),
        )
    layout = require_feasible(scene, load_layout(best, scene), str(best))
    rank: int | None = None
    objective: float | None = None
    summary_path = run_dir / "summary.json"
    if os.path.lexists(summary_path):
        summary = read_json(summary_path, "summary")
        if isinstance(summary, dict):
            r, o = summary.get("verified_rank"), summary.get("objective")
            rank = r if isinstance(r, int) and not isinstance(r, bool) else None
            objective = float(o) if isinstance(o, int | float) and math.isfinite(o) else None
    return [(layout, Elite(str(run_dir), rank, 1, objective))]


# --- bootstrap over groups of layouts ------------------------------------------------------


class GroupStats:
    """Per-group sums of the picks that :data:`INTERVAL_KEYS` are computed from, so that a
    bootstrap resample (how often each group is drawn) gives each statistic of the pooled
    picks of the drawn groups by a matrix product (what :func:`metrics` gives on them)."""

    def __init__(self, groups: Sequence[Sequence[PickResult]]) -> None:
        goals = sorted({p.true_goal for picks in groups for p in picks})
        col = {g: j for j, g in enumerate(goals)}
        shape = (len(groups), len(goals))
        self.n = np.zeros(len(groups))
        self.true = np.zeros(len(groups))
        self.wrong = np.zeros(len(groups))
        self.correct = np.zeros(len(groups))
        self.acted = np.zeros(len(groups))
        self.completed = np.zeros(len(groups))
        self.t_sum = np.zeros(len(groups))
        self.t_count = np.zeros(len(groups))
        self.goal_hits = np.zeros(shape)
        self.goal_total = np.zeros(shape)
        for g, picks in enumerate(groups):
            for p in picks:
                self.n[g] += 1
                self.true[g] += p.commit_true
                self.wrong[g] += p.committed is not None and p.committed != p.true_goal
                self.correct[g] += p.correct
                if p.feasible and (p.committed is not None or p.confirmed is not None):
                    self.acted[g] += 1
                    self.completed[g] += p.completed
                if p.commit_time is not None:
                    self.t_sum[g] += p.commit_time
                    self.t_count[g] += 1
                self.goal_total[g, col[p.true_goal]] += 1
                self.goal_hits[g, col[p.true_goal]] += p.commit_true
        samples = [km_sample(picks) for picks in groups]
        self.km = km_counts(samples)
        self.km_subjects = np.array([len(times) for times, _ in samples], dtype=np.float64)

    def __len__(self) -> int:
        return self.n.size

    def statistics(self, counts: FloatArray) -> dict[str, FloatArray]:
        """Each key of :data:`INTERVAL_KEYS` for every row of ``counts`` (``(B, G)``: how
        often each group is drawn); ``nan`` where undefined (no pick, no timed commit, no
        pick with inference, no pick acted on), ``inf`` for a Kaplan–Meier median never reached."""

        def ratio(num: FloatArray, den: FloatArray) -> FloatArray:
            top, bottom = counts @ num, counts @ den
            with np.errstate(divide="ignore", invalid="ignore"):
                out: FloatArray = np.where(
                    bottom > 0, top / np.where(bottom > 0, bottom, 1), np.nan
                )
            return out

        per_goal = ratio(self.goal_hits, self.goal_total)
        has = ~np.isnan(per_goal)
        min_goal = np.where(
            has.any(axis=-1), np.min(np.where(has, per_goal, np.inf), axis=-1), np.nan
        )
        u, d, r = self.km
        return {
            "commit_true_rate": ratio(self.true, self.n),
            "commit_rate_min_goal": min_goal,
            "wrong_commit_rate": ratio(self.wrong, self.n),
            "accuracy": ratio(self.correct, self.n),
            "completion_committed": ratio(self.completed, self.acted),
            "t_infer_mean": ratio(self.t_sum, self.t_count),
            "t_infer_km_median": np.where(
                counts @ self.km_subjects > 0, km_median_counts(u, counts @ d, counts @ r), np.nan
            ),
        }

    def intervals(
        self, seed: Sequence[int], n: int = RESAMPLES, level: float = LEVEL
    ) -> dict[str, list[float | None] | None]:
        """95 % (``level``) percentile bootstrap intervals of every key, the same ``n``
        resamples for all (seeded by ``seed``). JSON-ready: ``None`` for an interval that
        is undefined (fewer than two groups, or undefined in every resample), and for an
        infinite bound (a Kaplan–Meier median not reached in that many resamples)."""
        if len(self) < 2:
            return dict.fromkeys(INTERVAL_KEYS)
        # what bootstrap_ci_counts does, with one set of resamples for every key
        stats = self.statistics(resample_counts(len(self), np.random.default_rng(list(seed)), n))
        out: dict[str, list[float | None] | None] = {}
        for key in INTERVAL_KEYS:
            ci = percentile_interval(stats[key], level)
            out[key] = None if ci is None else [_finite(ci[0]), _finite(ci[1])]
        return out


def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


def interval_seed(seed: int, group: str) -> list[int]:
    """The seed of a report's bootstrap over ``group`` (``"layouts"`` or ``"runs"``)."""
    return [seed, 0xB007, {"layouts": 0, "runs": 1}[group]]


def group_intervals(report: dict[str, Any], group: str) -> dict[str, Any] | None:
    """The intervals over ``group`` (``"layouts"``, ``"runs"``) of a :func:`run_eval`
    report, ``None`` when it has none.

    A report written before ``completion_committed`` was among :data:`INTERVAL_KEYS` gets
    that interval recomputed from its ``per_layout`` rows (completed and acted-on picks per
    layout, or per run): the same groups in the same order and the same seeded resamples, so
    it is the interval :func:`run_eval` gives now. Without usable rows it stays absent.
    """
    a = report["aggregate"]
    iv = a.get("intervals") or {}
    ci: dict[str, Any] | None = iv.get(group)
    if ci is None or "completion_committed" in ci:
        return ci
    rows: list[dict[str, Any]] = report.get("per_layout") or []
    if not rows or not all("completion_committed" in r and "episodes" in r for r in rows):
        return ci
    keys = [r.get("run") if group == "runs" else r.get("index") for r in rows]
    if any(k is None for k in keys):
        return ci
    order = list(dict.fromkeys(keys))
    if len(order) != ci.get("groups"):
        return ci
    num, den = np.zeros(len(order)), np.zeros(len(order))
    for r, key in zip(rows, keys, strict=True):
        c = counts_of(r)
        num[order.index(key)] += c["completed"]
        den[order.index(key)] += c["acted_on"]
    rng = np.random.default_rng(interval_seed(int(report["seed"]), group))
    out = ratio_interval(num, den, rng, int(iv.get("resamples", RESAMPLES)),
                         float(iv.get("level", LEVEL)))  # fmt: skip
    return {**ci, "completion_committed": None if out is None else [out[0], out[1]]}


def run_eval(
    scene: Scene,
    layouts: Sequence[Layout],
    seed: int,
    *,
    params: Params | None = None,
    workers: int = 2,
    progress: Callable[[int], object] | None = None,
    episodes_per_goal: int | None = None,
    elites: Sequence[Elite] | None = None,
    resamples: int = RESAMPLES,
    operator: OperatorModel | None = None,
    arm: str = DEFAULT_ARM,
    assist: AssistPolicy = "commit",
) -> dict[str, Any]:
    """Evaluate ``layouts``; returns the report (JSON-ready).

    Args:
        scene, layouts, seed: what to evaluate; layout ``i``'s picks are seeded by
            ``(seed, i)``.
        params: observer and user-model parameters.
        workers: processes (1: in this process).
        progress: called with 1 after each layout.
        episodes_per_goal: N picks per candidate goal per layout instead of the paper's
            pick orders (all permutations, 120 sampled for M >= 5).
        elites: per layout, the optimisation run and elite it comes from
            (:func:`load_elites`); adds ``by_elite`` (per position among the runs' verified
            elites) and, with two runs or more, intervals over runs.
        resamples: bootstrap resamples of the intervals.
        operator: the simulated user steers like this operator (method.md §10, with the
            robot's clip) instead of section 2's user; recorded as ``operator``.
        arm: the stand-in's arm; recorded as ``arm``.
        assist: the help before the commit (:mod:`legws_daemon.core.arbitration`);
            recorded as ``assist``, in the report and its ``aggregate``.

    The report's ``aggregate`` holds :func:`metrics` over the pooled picks and
    ``intervals``: percentile bootstrap intervals (level 95 %) of :data:`INTERVAL_KEYS`
    resampling layouts (``intervals.layouts``) and, with two runs or more, runs
    (``intervals.runs``: a run's layouts are drawn together), each statistic recomputed
    over the pooled picks of the drawn groups; seeded by ``seed``.
    """
    params = params or Params()
    if elites is not None and len(elites) != len(layouts):
        raise InputError(f"{len(elites)} elites for {len(layouts)} layouts")
    arm_dir(None, arm)  # a missing or damaged robot model: one line here, not in each worker
    started = time.perf_counter()
    jobs: list[Job] = [
        (i, dict(layout), seed, episodes_per_goal) for i, layout in enumerate(layouts)
    ]
    results: dict[int, tuple[dict[str, Any], list[PickResult]]] = {}
    if workers <= 1:
        _init_worker(scene.source, params, operator, arm, assist)
        for job in jobs:
            i, extra, picks = _evaluate(job)
            results[i] = (extra, picks)
            if progress:
                progress(1)
    else:
        with ProcessPoolExecutor(
            max_workers=workers,
            initializer=_init_worker,
            initargs=(scene.source, params, operator, arm, assist),
            mp_context=worker_context(),
        ) as pool:
            for i, extra, picks in pool.map(_evaluate, jobs):
                results[i] = (extra, picks)
                if progress:
                    progress(1)
    seconds = time.perf_counter() - started
    per_layout = []
    all_picks: list[PickResult] = []
    for i, layout in enumerate(layouts):
        extra, picks = results[i]
        all_picks += picks
        source: dict[str, Any] = {}
        if elites is not None:
            e = elites[i]
            source = {"run": e.run, "elite_rank": e.rank, "elite_position": e.position,
                      "elite_objective": e.objective}  # fmt: skip
        per_layout.append(
            {"index": i, "layout": layout_to_data(layout), **source, **extra, **metrics(picks)}
        )
    accs = [row["accuracy"] for row in per_layout]
    episodes = sum(p.feasible for p in all_picks)
    simulated = sum(p.duration for p in all_picks)
    by_layout = [results[i][1] for i in range(len(layouts))]
    intervals: dict[str, Any] = {
        "level": LEVEL,
        "resamples": resamples,
        "layouts": {
            "groups": len(layouts),
            **GroupStats(by_layout).intervals(interval_seed(seed, "layouts"), resamples),
        },
    }
    runs = list(dict.fromkeys(e.run for e in elites)) if elites is not None else []
    if len(runs) > 1:
        assert elites is not None
        by_run = [[p for i, e in enumerate(elites) if e.run == run for p in by_layout[i]]
                  for run in runs]  # fmt: skip
        intervals["runs"] = {
            "groups": len(runs),
            **GroupStats(by_run).intervals(interval_seed(seed, "runs"), resamples),
        }
    aggregate = {
        "assist": assist,
        **metrics(all_picks),
        "accuracy_layout_mean": float(np.mean(accs)) if accs else None,
        "accuracy_layout_sd": float(np.std(accs, ddof=1)) if len(accs) > 1 else 0.0,
        "layouts_all_feasible": sum(not row["infeasible"] for row in per_layout),
        "intervals": intervals,
    }
    report: dict[str, Any] = {
        "scene": scene.name,
        "tier": scene.spec.tier,
        "m": len(scene.goal_names),
        "layouts": len(layouts),
        "seed": seed,
        "episodes_per_goal": episodes_per_goal,
        "params": params.as_dict(),
        "user": "section 2's simulated user" if operator is None else "operator",
        "operator": None if operator is None else operator.as_dict(),
        "arm": arm,
        "assist": assist,
        "summary": summary_of(aggregate, assist),
        "aggregate": aggregate,
        "timing": {
            "seconds": seconds,
            "workers": workers,
            "episodes": episodes,
            "episodes_per_second": episodes / seconds if seconds > 0 else None,
            "simulated_seconds": simulated,
        },
        "per_layout": per_layout,
    }
    if elites is not None:
        report["runs"] = runs
        positions = sorted({e.position for e in elites})

        def at(k: int) -> list[PickResult]:
            return [p for i, e in enumerate(elites) if e.position == k for p in by_layout[i]]

        report["by_elite"] = [
            {"position": k, "layouts": sum(e.position == k for e in elites), **metrics(at(k))}
            for k in positions
        ]
    return report


#: The overall summary's keys (``legws eval --json``'s ``summary``), from the aggregate.
SUMMARY_KEYS = (
    "time_to_grasp_s",
    "time_to_task_s",
    "effort",
    "robot_share",
    "wrong_grasp_rate",
    "overrides",
    "completion",
    "commit_true_rate",
    "t_infer_km_median",
)


def summary_of(aggregate: dict[str, Any], assist: str) -> dict[str, Any]:
    """The overall summary: the policy, the value of its help over all picks (mean time to
    grasp and to the task, s; effort, s at full deflection; the robot's share of the
    approach; wrong grasps; overrides; completion of the picks acted on) and the count of
    picks behind them."""
    counts = aggregate["counts"]
    return {
        "assist": assist,
        **{k: aggregate.get(k) for k in SUMMARY_KEYS},
        "picks": counts["picks"],
        "acted_on": counts["acted_on"],
        "completed": counts["completed"],
        "wrong_grasps": counts["wrong_grasps"],
    }


# --- the whole numbers behind the rates, and their intervals -------------------------------

#: The rates that get an interval, with the counts they are ``k`` of ``n`` of.
RATE_KEYS = (
    "commit_true_rate",
    "commit_rate_min_goal",
    "wrong_commit_rate",
    "accuracy",
    "completion_committed",
)


def counts_of(m: dict[str, Any]) -> dict[str, Any]:
    """The counts behind the rates of a :func:`~legws_daemon.sim.protocol.metrics` dict
    (``aggregate``, a ``per_layout`` or ``by_elite`` row): its ``counts``, or for a report
    written before they were kept, the same recovered from the rates. That is exact: every
    rate is ``k / n`` in floating point with ``n`` = ``episodes`` (``round`` gives ``k``
    back), every pick order picks every goal once (``episodes / M`` picks per goal), and
    ``completion_committed`` is completed over acted-on picks; with none of them completed
    the acted-on picks are the committed and the confirmed ones."""
    if isinstance(m.get("counts"), dict):
        counts: dict[str, Any] = m["counts"]
        return counts
    n = int(m["episodes"])

    def k(rate: float | None, of: int = n) -> int:
        return 0 if rate is None else round(rate * of)

    completed = k(m.get("completion_rate"))
    share = m.get("completion_committed")
    if share is None:
        acted = 0
    elif share > 0:
        acted = round(completed / share)
    else:
        acted = k((m.get("commit_rate") or 0.0) + (m.get("confirmed_rate") or 0.0))
    by_goal: dict[str, float] = m.get("commit_rate_by_goal") or {}
    per_goal = n // len(by_goal) if by_goal and n % len(by_goal) == 0 else 0
    return {
        "picks": n,
        "commit_true": k(m.get("commit_true_rate")),
        "wrong_commit": k(m.get("wrong_commit_rate")),
        "correct": k(m.get("accuracy")),
        "acted_on": acted,
        "completed": completed,
        "goal_picks": {g: per_goal for g in by_goal} if per_goal else {},
        "goal_commit_true": {g: k(r, per_goal) for g, r in by_goal.items()} if per_goal else {},
    }


def _worst_goal(counts: dict[str, Any]) -> tuple[int, int] | None:
    """``(k, n)`` of the goal with the lowest commit rate on the true goal: of those tied at
    100 %, the one with the fewest picks (the weakest bound); at 0 %, the most (the
    tightest); ``None`` without per-goal counts."""
    picks: dict[str, int] = counts.get("goal_picks") or {}
    hits: dict[str, int] = counts.get("goal_commit_true") or {}
    pairs = [(hits[g], n) for g, n in picks.items() if n > 0 and g in hits]
    if not pairs:
        return None
    low = min(pairs, key=lambda kn: kn[0] / kn[1])
    tied = [kn for kn in pairs if kn[0] * low[1] == low[0] * kn[1]]
    if low[0] == low[1]:
        return min(tied, key=lambda kn: kn[1])
    return max(tied, key=lambda kn: kn[1])


def rate_counts(m: dict[str, Any], key: str) -> tuple[int, int] | None:
    """``(k, n)`` of the rate ``key`` of :data:`RATE_KEYS` in the metrics dict ``m``
    (:func:`counts_of`); ``None`` when it cannot be told."""
    c = counts_of(m)
    if key == "commit_rate_min_goal":
        return _worst_goal(c)
    if key == "completion_committed":
        return int(c["completed"]), int(c["acted_on"])
    k = {"commit_true_rate": "commit_true", "wrong_commit_rate": "wrong_commit",
         "accuracy": "correct"}[key]  # fmt: skip
    return int(c[k]), int(c["picks"])


def rate_intervals(m: dict[str, Any], ci: dict[str, Any] | None) -> dict[str, RateInterval | None]:
    """Every rate of :data:`RATE_KEYS` in ``m`` with its interval (:func:`rate_interval`):
    Clopper–Pearson where every pick or none succeeded, else the bootstrap of ``ci`` (one
    group's ``intervals``, or ``None``); ``None`` for a rate that is undefined or whose counts
    cannot be told."""
    out: dict[str, RateInterval | None] = {}
    for key in RATE_KEYS:
        kn = rate_counts(m, key) if m.get(key) is not None else None
        out[key] = None if kn is None else rate_interval(*kn, (ci or {}).get(key))
    return out


def outward_percent(x: float, digits: int, side: Literal["low", "high"]) -> str:
    """The bound ``x`` (a fraction) in per cent with ``digits`` decimals, rounded away from
    the rate it bounds: a Clopper–Pearson lower bound of 98.99 % reads 98.9, never 99.0 (a
    target such as "at least 99 %" is judged on it), an upper bound of 1.22 % reads 1.3."""
    scale = 10**digits
    scaled = 100 * x * scale
    rounded = math.floor(scaled + 1e-9) if side == "low" else math.ceil(scaled - 1e-9)
    return f"{rounded / scale:.{digits}f}"


def format_rate(
    r: RateInterval | None, digits: int = 1, bound_digits: int = 1, unit: str = " %"
) -> str:
    """A rate with its interval, in per cent: ``76.1 % [69.0, 83.0]`` (the bootstrap),
    ``100.0 % [≥ 98.7]`` / ``0.0 % [≤ 1.3]`` (Clopper–Pearson, every pick / no pick of ``n``),
    ``75.0 % (no spread)`` (every group the same), or the rate alone. Bootstrap bounds take
    ``digits`` decimals, the Clopper–Pearson ones ``bound_digits``, rounded outward
    (:func:`outward_percent`)."""
    if r is None or r.rate is None:
        return "—"
    value = f"{100 * r.rate:.{digits}f}{unit}"
    if r.kind == "at_least" and r.low is not None:
        return f"{value} [≥ {outward_percent(r.low, bound_digits, 'low')}]"
    if r.kind == "at_most" and r.high is not None:
        return f"{value} [≤ {outward_percent(r.high, bound_digits, 'high')}]"
    if r.kind == "no_spread":
        return f"{value} (no spread)"
    if r.kind == "bootstrap" and r.low is not None and r.high is not None:
        return f"{value} [{100 * r.low:.{digits}f}, {100 * r.high:.{digits}f}]"
    return value


#: What every rate and time of the protocol holds for (method.md §2), in words.
USER_MODEL = (
    "the simulated user of method.md §2 (aimed straight at the goal's grasp at full "
    "deflection, white Gaussian velocity noise σ = {sigma:g} m/s, the deflection clipped to "
    "|u| ≤ 1, i.e. speed ≤ v_max = {v_max:g} m/s; confirming at the grasp), on the MuJoCo "
    "stand-in; not a given person"
)

#: The notation of the intervals on rates, said once above every table that has them.
RATE_NOTATION = (
    "Rates with 95 % intervals: `[low, high]` a percentile bootstrap over the groups "
    "(layouts or optimisation runs, which accounts for the picks of one layout being alike); "
    "where every pick counted succeeded (k = n) or none did (k = 0) the bootstrap cannot leave "
    "100 % or 0 %, so `[≥ low]` / `[≤ high]` is the Clopper–Pearson bound on k of n picks "
    "instead (picks taken as independent; n: all picks, for the worst goal that goal's, for "
    "completion the picks acted on); `(no spread)`: every group has the same rate, so "
    "resampling them gives no interval."
)


def user_model(params: dict[str, Any] | None) -> str:
    """:data:`USER_MODEL` with a report's ``params`` (method.md §2's values without)."""
    p = params or {}
    return USER_MODEL.format(sigma=p.get("sigma", 0.03), v_max=p.get("v_max", 0.05))


def _who(report: dict[str, Any]) -> str:
    """Whom a report's users simulate: section 2's user, or an operator (method.md §10)."""
    op = report.get("operator")
    if not op:
        return user_model(report.get("params"))
    return (
        f"a simulated operator (method.md §10: speed {op['speed']:.2f}, sigma "
        f"{op['sigma']:.3f} m/s, rho {op['rho']:.2f}, bias {op['bias_deg']:+.1f}°, "
        f"{op['steering']} steering, clipped to the robot's speed), on the stand-in"
    )


def _pct(x: float | None) -> str:
    return "—" if x is None else f"{100 * x:.1f} %"


def _sec(x: float | None) -> str:
    return "—" if x is None else f"{x:.1f}"


def _rate(x: float | None) -> str:
    return "—" if x is None else f"{x:.0f}"


def _bound(x: float | None, pct: bool) -> str:
    if x is None:
        return "∞"
    return f"{100 * x:.1f}" if pct else f"{x:.1f}"


def _with_ci(value: str, ci: list[float | None] | None, pct: bool) -> str:
    """``value [low, high]`` (``∞``: a bound beyond the longest time observed)."""
    if ci is None:
        return value
    return f"{value} [{_bound(ci[0], pct)}, {_bound(ci[1], pct)}]"


def _km(m: dict[str, Any]) -> str:
    """The Kaplan–Meier median, or ``> longest time`` when it is never reached."""
    if m["t_infer_km_median"] is not None:
        return _sec(m["t_infer_km_median"])
    if m["t_infer_km_max_time"] is None:
        return "—"
    return f"> {_sec(m['t_infer_km_max_time'])}"


def _person_row(label: str, m: dict[str, Any], ci: dict[str, Any] | None) -> str:
    c = ci or {}
    rates = rate_intervals(m, ci)
    cells = " | ".join(format_rate(rates[key]) for key in RATE_KEYS)
    return (
        f"| {label} | {cells} "
        f"| {_with_ci(_sec(m['t_infer_mean']), c.get('t_infer_mean'), False)} "
        f"| {_with_ci(_km(m), c.get('t_infer_km_median'), False)} "
        f"| {m['t_infer_km_picks']} ({m['t_infer_km_events']}) |"
    )


PERSON_HEADER = (
    "| {what} | commit on the true goal | min over goals | wrong commit | accuracy "
    "| completed, acted on | T_infer mean (s) | T_infer KM median (s) | KM picks (events) |"
)


def markdown(report: dict[str, Any]) -> str:
    """The report as Markdown: the aggregate row, the person's metrics with their
    intervals (and per elite position), the failures, then one row per layout."""
    a = report["aggregate"]
    t_infer = (
        f"{_sec(a['t_infer_mean'])} ± {_sec(a['t_infer_sd'])}"
        if a["t_infer_mean"] is not None
        else "—"
    )
    n_goal = report.get("episodes_per_goal")
    picks = "all pick orders" if n_goal is None else f"{n_goal} picks per goal"
    iv = a["intervals"]
    lines = [
        f"## {report['scene']} ({report['tier'] or 'demo'}, M = {report['m']}): "
        f"{report['layouts']} layouts, {picks}, seed {report['seed']}",
        "",
        "| accuracy | accuracy, feasible picks | T_infer (s) | commit | wrong commit | no commit "
        "| confirmed | completed | completed, acted on | infeasible picks | picks | picks/s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
        f"| {_pct(a['accuracy'])} | {_pct(a['accuracy_feasible'])} | {t_infer} "
        f"| {_pct(a['commit_rate'])} | {_pct(a['wrong_commit_rate'])} "
        f"| {_pct(a['no_commit_rate'])} | {_pct(a['confirmed_rate'])} "
        f"| {_pct(a['completion_rate'])} | {_pct(a['completion_committed'])} "
        f"| {a['infeasible_picks']} | {a['episodes']} "
        f"| {_rate(report['timing']['episodes_per_second'])} |",
        "",
        f"As the person sees them (method.md §9), for {_who(report)}.",
        "",
        RATE_NOTATION.replace("95 %", f"{100 * iv['level']:.0f} %")
        + f" Bootstrap: {iv['resamples']} resamples; none with one group.",
        "",
        PERSON_HEADER.format(what="intervals over"),
        "|---|---|---|---|---|---|---|---|---|",
        _person_row(f"layouts ({iv['layouts']['groups']})", a, iv["layouts"]),
    ]
    if "runs" in iv:
        lines.append(_person_row(f"runs ({iv['runs']['groups']})", a, iv["runs"]))
    by_goal = ", ".join(f"{g} {_pct(r)}" for g, r in a["commit_rate_by_goal"].items())
    lines += [
        "",
        f"Commit on the true goal per goal: {by_goal or '—'}; single-candidate commits "
        f"(no inference) {_pct(a['single_commit_rate'])} of the picks.",
    ]
    if "by_elite" in report:
        lines += [
            "",
            f"Per elite (1: each run's best verified; {len(report['runs'])} runs):",
            "",
            PERSON_HEADER.format(what="elite"),
            "|---|---|---|---|---|---|---|---|---|",
        ]
        lines += [_person_row(str(row["position"]), row, None) for row in report["by_elite"]]
    source = "by_elite" in report
    lines += [
        "",
        "Failures: " + (", ".join(f"{k} {v}" for k, v in a["failures"].items()) or "none") + ".",
        "",
        "| layout | " + ("run, elite | " if source else "") + "accuracy | T_infer (s) "
        "| commit | wrong | no commit | completed | infeasible grasps | other failures |",
        "|---|---|---|---|---|---|---|---|---|" + ("---|" if source else ""),
    ]
    for row in report["per_layout"]:
        bad = ", ".join(f"{n} ({r})" for n, r in row["infeasible"].items()) or "—"
        other = {k: v for k, v in row["failures"].items() if k != "infeasible_grasp"}
        others = ", ".join(f"{k} {v}" for k, v in other.items()) or "—"
        where = f"{Path(row['run']).name}, {row['elite_position']} | " if source else ""
        lines.append(
            f"| {row['index']} | {where}{_pct(row['accuracy'])} | {_sec(row['t_infer_mean'])} "
            f"| {_pct(row['commit_rate'])} | {_pct(row['wrong_commit_rate'])} "
            f"| {_pct(row['no_commit_rate'])} | {_pct(row['completion_rate'])} | {bad} "
            f"| {others} |"
        )
    return "\n".join(lines) + "\n"


__all__ = [
    "INTERVAL_KEYS",
    "RATE_KEYS",
    "RATE_NOTATION",
    "USER_MODEL",
    "Elite",
    "GroupStats",
    "counts_of",
    "format_rate",
    "group_intervals",
    "interval_seed",
    "load_elites",
    "markdown",
    "outward_percent",
    "random_layouts",
    "rate_counts",
    "rate_intervals",
    "run_eval",
    "user_model",
]

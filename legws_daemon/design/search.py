"""Quality-diversity search over layouts with pyribs: CMA-ME (default), MAP-Elites, CMA-MAE.

All three share the archive of method.md §5 — a 20 × 20 grid over (mean pairwise distance,
centroid offset), ranges from the 5th/95th percentiles of 10,000 random layouts — and three
emitters of batch 30; they differ in the emitters:

* ``cma-me``: evolution-strategy emitters, ``sigma0 = 0.08``, two-stage improvement ranking;
* ``map-elites``: Gaussian emitters (isotropic mutation, ``sigma = 0.08``);
* ``cma-mae``: evolution-strategy emitters with improvement ranking on a soft archive
  (learning rate 0.01), elites kept in a separate result archive.

Every component is seeded from one seed: same seed, same result.

pyribs compiles its evolution strategy's numba helpers on first use in every process
(~4-8 s here, a third of a search's budget); :func:`cache_ribs_kernels` lets numba keep
them in its cache (``$NUMBA_CACHE_DIR``), so that only the first run on a machine pays.
Its grid archive groups each batch by cell with numpy-groupies' numba ``aggregate``, which
compiles ~30 specialisations on first use (~8 s of CPU in every fresh process or cache);
:func:`archive_on_numpy` hands the archive numpy-groupies' numpy implementation instead —
the same results, ties included (the package's implementations agree by its own tests;
checked here on an archive's tied batches), and as fast on batches of 90 (2000 adds: 0.3
s against 1.0 s, and 0.9 against 0.7 s on the soft archive).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from ribs.archives import GridArchive
from ribs.emitters import EvolutionStrategyEmitter, GaussianEmitter
from ribs.schedulers import Scheduler

from legws_daemon.core.geometry import FloatArray
from legws_daemon.design import METHODS
from legws_daemon.design.problem import LayoutProblem
from legws_daemon.errors import InputError

GRID = (20, 20)
EMITTERS = 3
BATCH = 30
SIGMA0 = 0.08
#: Lowest objective CMA-MAE's soft archive accepts (below any feasible layout's J).
MAE_THRESHOLD_MIN = -50.0
MAE_LEARNING_RATE = 0.01


@dataclass(frozen=True, slots=True)
class Elite:
    solution: FloatArray
    objective: float
    measures: FloatArray


@dataclass
class SearchResult:
    """The archive after the search, elites best first."""

    method: str
    elites: list[Elite]
    coverage: float
    feasible_coverage: float
    qd_score: float
    evaluations: int
    iterations: int
    seconds: float
    ranges: list[tuple[float, float]]
    table: list[dict[str, Any]]  # per elite: cell, measures, objective, J, (K, R,) score, feasible


def cache_ribs_kernels() -> None:
    """Keep pyribs' CMA-ES numba helpers in numba's on-disk cache (the same compiled code;
    pyribs declares them without ``cache=True``). Where no cache folder can be written,
    they compile as before."""
    from ribs.emitters.opt import _cma_es

    strategy = getattr(_cma_es, "CMAEvolutionStrategy", None)
    for name in ("_transform_and_check_sol", "_calc_cov_update"):
        kernel = getattr(strategy, name, None)
        enable = getattr(kernel, "enable_caching", None)
        if enable is None or type(getattr(kernel, "_cache", None)).__name__ != "NullCache":
            continue  # not a numba dispatcher, or already caching
        try:
            enable()
        except RuntimeError:  # no writable cache folder: compile per process, as before
            return


def archive_on_numpy() -> None:
    """pyribs' archives group a batch by cell with numpy-groupies' numpy ``aggregate``
    rather than its numba one (same results; no compilation)."""
    import numpy_groupies
    from ribs.archives import _grid_archive

    if getattr(_grid_archive, "aggregate", None) is not None:
        setattr(_grid_archive, "aggregate", numpy_groupies.aggregate_np)  # noqa: B010


def _scheduler(
    problem: LayoutProblem,
    method: str,
    seed: int,
    x0s: FloatArray,
    ranges: list[tuple[float, float]],
) -> tuple[Scheduler, GridArchive]:
    seeds = np.random.SeedSequence(seed).generate_state(EMITTERS + 2)
    kw: dict[str, Any] = {"solution_dim": problem.dim, "dims": GRID, "ranges": ranges}
    if method == "cma-mae":
        archive = GridArchive(
            **kw,
            learning_rate=MAE_LEARNING_RATE,
            threshold_min=MAE_THRESHOLD_MIN,
            seed=int(seeds[0]),
        )
        result = GridArchive(**kw, seed=int(seeds[1]))
        mae_emitters = [
            EvolutionStrategyEmitter(
                archive,
                x0=x0s[i],
                sigma0=SIGMA0,
                ranker="imp",
                selection_rule="mu",
                restart_rule="basic",
                batch_size=BATCH,
                seed=int(seeds[2 + i]),
            )
            for i in range(EMITTERS)
        ]
        return Scheduler(archive, mae_emitters, result_archive=result), result
    archive = GridArchive(**kw, seed=int(seeds[0]))
    emitters: list[EvolutionStrategyEmitter | GaussianEmitter]
    if method == "cma-me":
        emitters = [
            EvolutionStrategyEmitter(
                archive,
                x0=x0s[i],
                sigma0=SIGMA0,
                ranker="2imp",
                batch_size=BATCH,
                seed=int(seeds[2 + i]),
            )
            for i in range(EMITTERS)
        ]
    else:
        emitters = [
            GaussianEmitter(
                archive,
                sigma=SIGMA0,
                initial_solutions=x0s[i : i + 1],
                batch_size=BATCH,
                seed=int(seeds[2 + i]),
            )
            for i in range(EMITTERS)
        ]
    return Scheduler(archive, emitters), archive


def search(
    problem: LayoutProblem,
    method: str = "cma-me",
    iterations: int = 1000,
    seed: int = 0,
    progress: Callable[[int, float, float], None] | None = None,
) -> SearchResult:
    """Run the search; ``progress(iteration, best, coverage)`` is called every iteration with
    the best feasible score so far (J, -K with the commit objective, R with the rate)."""
    if method not in METHODS:
        raise InputError(
            f"unknown method '{method}'; known: {', '.join(METHODS)}", field="--method"
        )
    started = time.perf_counter()
    cache_ribs_kernels()
    archive_on_numpy()
    rng = np.random.default_rng([seed, 0x0F7])
    ranges = problem.measure_ranges(rng)
    x0s = problem.encode(problem.constraints.sample(EMITTERS, rng))
    scheduler, archive = _scheduler(problem, method, seed, x0s, ranges)
    evaluations = 0
    best = -np.inf
    for it in range(1, iterations + 1):
        x = scheduler.ask()
        ev = problem.evaluate(x)
        scheduler.tell(ev.objective, ev.measures)
        evaluations += len(x)
        feasible_score = ev.score[ev.feasible]
        if len(feasible_score):
            best = max(best, float(feasible_score.max()))
        if progress is not None:
            progress(it, best, float(archive.stats.coverage))
    data = archive.data()
    order = np.argsort(-data["objective"], kind="stable")
    solutions = data["solution"][order]
    final = problem.evaluate(solutions) if len(solutions) else None
    elites = [
        Elite(solutions[i], float(data["objective"][order][i]), data["measures"][order][i])
        for i in range(len(solutions))
    ]
    table = []
    if final is not None:
        for i in range(len(solutions)):
            row = {
                "cell": int(data["index"][order][i]),
                "mean_pairwise_distance": float(final.measures[i, 0]),
                "centroid_offset": float(final.measures[i, 1]),
                "objective": float(final.objective[i]),
                "certificate": float(final.certificate[i]),
                "feasible_screen": bool(final.feasible[i]),
            }
            if final.commit is not None:
                row["commit_objective"] = float(final.commit[i])
            if final.rate is not None:
                row["commit_rate_estimate"] = float(final.rate[i])
            if final.time is not None:
                row["commit_time_estimate"] = float(final.time[i])
            row["score"] = float(final.score[i])  # what was searched: J, -K, R or -T
            table.append(row)
    cells = GRID[0] * GRID[1]
    feasible_cells = int(final.feasible.sum()) if final is not None else 0
    return SearchResult(
        method=method,
        elites=elites,
        coverage=float(archive.stats.coverage),
        feasible_coverage=feasible_cells / cells,
        qd_score=float(archive.stats.qd_score),
        evaluations=evaluations,
        iterations=iterations,
        seconds=time.perf_counter() - started,
        ranges=ranges,
        table=table,
    )

"""Compile the optimiser's numba kernels once, into numba's on-disk cache.

numba compiles a kernel the first time a process uses it and finds no cached copy in
``$NUMBA_CACHE_DIR`` (the design objectives of :mod:`~legws_daemon.design.fast_objectives`,
the compiled Monte Carlo rollouts of :mod:`~legws_daemon.core.rollout_kernels`, pyribs'
CMA-ES helpers): ~30 s of CPU on this machine before a first ``legws optimize`` does any
work, and as much again in every process that starts before the cache is written (the
test suite's workers, a process pool's). :func:`compile_kernels` pays it once, on a tiny
problem of every objective; ``legws assets kernels`` runs it and set-up (``./dev``) calls
that beside its other steps.
"""

from __future__ import annotations

import time
from typing import cast

import numpy as np

from legws_daemon.core.montecarlo import monte_carlo, monte_carlo_commit
from legws_daemon.core.operator import STEERINGS, OperatorModel, Steering
from legws_daemon.core.params import Params
from legws_daemon.design import OBJECTIVES
from legws_daemon.design.problem import LayoutProblem
from legws_daemon.scene.catalog import load_scene

#: Layouts per objective evaluation, and search iterations, of the warm-up: enough to reach
#: every kernel once.
BATCH = 4
ITERATIONS = 2
#: Monte Carlo trials of the warm-up.
TRIALS = 8


def compile_kernels(scene_name: str = "desk") -> dict[str, float]:
    """Use every compiled kernel once on ``scene_name`` (its goals as they stand and a few
    random layouts); returns the seconds each part took (compiling, or loading from the
    cache when it is there)."""
    from legws_daemon.design.search import search

    scene = load_scene(scene_name)
    rng = np.random.default_rng(0)
    took: dict[str, float] = {}
    # section 2's user, and one person of method.md §10 (the objectives for operators: the
    # slack's kernel too, and every steering)
    people = [
        OperatorModel(0.7, 0.04, 0.5, 5.0, cast(Steering, steering)) for steering in STEERINGS
    ]
    for objective in OBJECTIVES:
        t0 = time.perf_counter()
        for operators in ([], people):
            problem = LayoutProblem(scene, objective=objective, operators=operators)
            problem.evaluate(rng.uniform(size=(BATCH, problem.dim)))
        took[f"objective {objective}"] = time.perf_counter() - t0
    problem = LayoutProblem(scene)
    for method in ("cma-me", "cma-mae"):
        t0 = time.perf_counter()
        search(problem, method, ITERATIONS, seed=0)
        took[f"search {method}"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    goals, params = scene.goal_set(), Params()
    monte_carlo(goals, params, TRIALS, compiled=True)
    steps = [None] * len(goals.names)
    monte_carlo_commit(goals, params, TRIALS, rng, steps, compiled=True)
    took["monte carlo"] = time.perf_counter() - t0
    return took

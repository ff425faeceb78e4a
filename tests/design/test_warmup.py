"""The kernel warm-up (`legws assets kernels`, run by set-up): every compiled kernel of the
optimiser used once, so that numba's cache holds them for the processes after it."""

from __future__ import annotations

from pathlib import Path

import numba
import pytest

from legws_daemon.cli.main import run
from legws_daemon.design import OBJECTIVES


def _indexed(cache: Path) -> set[str]:
    """The kernels numba's cache holds an index for (``module.function``)."""
    return {p.name.split("-")[0] for p in cache.rglob("*.nbi")}


def test_the_warm_up_leaves_every_kernel_in_numbas_cache(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert run(["assets", "kernels"]) == 0
    lines = capsys.readouterr().out.splitlines()
    parts = [line.split(":")[0] for line in lines]
    assert parts == [f"objective {o}" for o in OBJECTIVES] + [
        "search cma-me",
        "search cma-mae",
        "monte carlo",
    ]
    assert all(line.endswith(" s") for line in lines)
    indexed = _indexed(Path(numba.config.CACHE_DIR))
    # the design objectives, the Monte Carlo rollouts and pyribs' CMA-ES helpers
    for kernel in (
        "fast_objectives._commit_kernel",
        "fast_objectives._slack_kernel",
        "rollout_kernels.walk_block",
        "rollout_kernels.commit_block",
        "_cma_es.CMAEvolutionStrategy._calc_cov_update",
    ):
        assert kernel in indexed, sorted(indexed)
    assert not run(["assets", "kernels", "--quiet"]) and capsys.readouterr().out == ""

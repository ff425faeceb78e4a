"""The search's pyribs set-up: the archive groups a batch by cell on numpy-groupies' numpy
implementation, with what pyribs relies on from its numba one (counts and sums per cell,
the first of tied best solutions)."""

from __future__ import annotations

import numpy as np
import numpy_groupies
from ribs.archives import GridArchive, _grid_archive

from legws_daemon.design.search import archive_on_numpy


def _archive(**kw: float) -> GridArchive:
    return GridArchive(solution_dim=1, dims=(2, 2), ranges=[(0, 1), (0, 1)], seed=1, **kw)


def test_the_archive_groups_on_numpy_and_keeps_the_first_of_tied_solutions() -> None:
    archive_on_numpy()
    assert getattr(_grid_archive, "aggregate") is numpy_groupies.aggregate_np  # noqa: B009
    archive = _archive()
    solutions = np.array([[1.0], [2.0], [3.0], [4.0]])
    objectives = np.array([0.5, 0.9, 0.9, 0.1])  # 2 and 3 tie in the first cell
    measures = np.array([[0.1, 0.1], [0.2, 0.2], [0.3, 0.3], [0.9, 0.9]])
    archive.add(solutions, objectives, measures)
    data = archive.data()
    kept = dict(zip(data["index"].tolist(), data["solution"][:, 0].tolist(), strict=True))
    assert sorted(kept.values()) == [2.0, 4.0]  # the first of the tie, and the lone one
    # the soft archive (CMA-MAE): the threshold moves by the mean of each cell's batch
    soft = _archive(learning_rate=0.5, threshold_min=0.0)
    soft.add(solutions, objectives, measures)
    thresholds = dict(zip(soft.data()["index"].tolist(), soft.data()["threshold"].tolist(),
                          strict=True))  # fmt: skip
    cell = soft.index_of_single(measures[0])
    # three solutions from 0: batch update 0 + (1 - (1 - 0.5)^3) (mean(0.5, 0.9, 0.9) - 0)
    assert thresholds[cell] == np.float64((1 - 0.5**3) * (2.3 / 3))

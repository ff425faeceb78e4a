"""The layout-design problem: encoding, objective and penalties, measures, capacity."""

from __future__ import annotations

import numpy as np
import pytest

from legws_daemon.core.certificate import certify
from legws_daemon.core.params import Params
from legws_daemon.design.optimize import check_capacity
from legws_daemon.design.problem import INFEASIBLE_OFFSET, LayoutProblem
from legws_daemon.errors import InfeasibleError, InputError
from legws_daemon.scene.catalog import load_scene


def test_encode_decode_round_trip_and_clipping() -> None:
    p = LayoutProblem(load_scene("meal_assembly"))
    poses = p.constraints.sample(20, np.random.default_rng(0))
    np.testing.assert_allclose(p.decode(p.encode(poses)), poses, atol=1e-12)
    x = np.full((1, p.dim), 1.7)  # out of bounds: positions clip, yaw wraps
    d = p.decode(x)[0]
    ws = p.scene.workspace
    np.testing.assert_allclose(d[:, 0], ws.x_range[1])
    np.testing.assert_allclose(d[:, 1], ws.y_range[1])
    np.testing.assert_allclose(d[:, 2], -np.pi + 0.7 * 2 * np.pi)


def test_objective_is_the_certificate_on_feasible_layouts() -> None:
    sc = load_scene("desk")
    p = LayoutProblem(sc)
    poses = p.constraints.sample(5, np.random.default_rng(1))
    ev = p.evaluate(p.encode(poses))
    assert ev.feasible.all()
    np.testing.assert_allclose(ev.objective, ev.certificate)
    for i in range(5):
        goals = sc.goal_set(p.constraints.to_layout(poses[i]), goals=p.names)
        assert ev.certificate[i] == pytest.approx(certify(goals, Params()).objective, rel=1e-9)


def test_infeasible_layouts_rank_below_every_feasible_one() -> None:
    p = LayoutProblem(load_scene("desk"))
    poses = p.constraints.sample(50, np.random.default_rng(2))
    bad = poses.copy()
    bad[:, 1, :2] = bad[:, 0, :2] + 0.01  # two objects 1.4 cm apart
    good, worse = p.evaluate(p.encode(poses)), p.evaluate(p.encode(bad))
    assert not worse.feasible.any()
    assert worse.violation.min() > 0
    assert worse.objective.max() < good.objective.min()
    np.testing.assert_allclose(
        worse.objective, worse.certificate - 100.0 * worse.violation - INFEASIBLE_OFFSET
    )


def test_measures() -> None:
    p = LayoutProblem(load_scene("breakfast_easy"))
    c = p.centre
    poses = np.array([[[c[0] - 0.1, c[1], 0.0], [c[0] + 0.1, c[1], 0.0]]])
    np.testing.assert_allclose(p.measures(poses), [[0.2, 0.0]], atol=1e-12)
    lo_hi = p.measure_ranges(np.random.default_rng(0))
    assert all(lo < hi for lo, hi in lo_hi)


def test_subset_and_bad_names() -> None:
    sc = load_scene("meal_assembly")
    p = LayoutProblem(sc, ["banana", "red_can"])
    assert p.dim == 6
    assert "cereal_box" in p.constraints.fixed_names
    with pytest.raises(InputError, match="fixed"):
        LayoutProblem(sc, ["banana", "bowl"])
    with pytest.raises(InputError, match="at least 2"):
        LayoutProblem(sc, ["banana"])


def test_impossible_problem_fails_at_once() -> None:
    sc = load_scene("cluttered")
    p = LayoutProblem(sc)
    from dataclasses import replace

    p.constraints = replace(p.constraints, min_clearance=0.4)  # 11 discs of 0.4 m
    with pytest.raises(InfeasibleError, match="no layout exists"):
        check_capacity(p)

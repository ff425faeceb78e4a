"""Layout constraints and random feasible layouts."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from legws_daemon.errors import InfeasibleError
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.constraints import LayoutConstraints


@pytest.mark.parametrize("name", ["breakfast_easy", "desk", "meal_assembly", "cluttered"])
def test_samples_are_feasible_and_uniform_in_yaw(name: str) -> None:
    sc = load_scene(name)
    cons = LayoutConstraints.of(sc)
    poses = cons.sample(200, np.random.default_rng(0))
    assert poses.shape == (200, len(sc.movable), 3)
    assert np.all(cons.violation(poses) == 0.0)
    for row in poses[:20]:
        assert cons.problems(cons.to_layout(row)) == []
    yaw = poses[..., 2].ravel()
    assert yaw.min() >= -np.pi and yaw.max() < np.pi
    assert abs(yaw.mean()) < 0.3


def test_same_seed_same_samples() -> None:
    cons = LayoutConstraints.of(load_scene("desk"))
    a = cons.sample(50, np.random.default_rng(4))
    b = cons.sample(50, np.random.default_rng(4))
    np.testing.assert_array_equal(a, b)


def test_violation_is_zero_exactly_when_there_are_no_problems() -> None:
    sc = load_scene("meal_assembly")
    cons = LayoutConstraints.of(sc)
    rng = np.random.default_rng(1)
    raw = np.stack(
        [
            rng.uniform(0.2, 0.95, (300, 5)),
            rng.uniform(-0.55, 0.55, (300, 5)),
            rng.uniform(-np.pi, np.pi, (300, 5)),
        ],
        axis=-1,
    )
    viol = cons.violation(raw)
    assert np.any(viol == 0) and np.any(viol > 0)
    for row, v in zip(raw, viol, strict=True):
        assert (v == 0) == (cons.problems(cons.to_layout(row)) == [])


def test_each_constraint_is_named() -> None:
    sc = load_scene("desk")
    cons = LayoutConstraints.of(sc)
    layout = sc.default_layout()
    mug, stapler = layout["white_mug"], layout["black_stapler"]
    bad = dict(layout)
    bad["white_mug"] = type(mug)(0.95, mug.y, 0.0)
    assert any("outside" in p for p in cons.problems(bad))
    bad = dict(layout)
    bad["white_mug"] = type(mug)(stapler.x + 0.05, stapler.y, 0.0)
    assert any("white_mug and black_stapler" in p for p in cons.problems(bad))
    bad = dict(layout)
    bad["white_mug"] = type(mug)(0.55, 0.05, 0.0)
    assert any("EE home" in p for p in cons.problems(bad))
    bad = dict(layout)
    bad["white_mug"] = type(mug)(0.80, 0.30, 0.0)
    assert any("fixed sticky_notes" in p for p in cons.problems(bad))


def test_subset_keeps_the_others_fixed() -> None:
    sc = load_scene("meal_assembly")
    cons = LayoutConstraints.of(sc, ["banana", "red_can"])
    assert cons.names == ("banana", "red_can")
    assert set(cons.fixed_names) == set(sc.objects) - {"banana", "red_can"}
    poses = cons.sample(100, np.random.default_rng(2))
    fixed = cons.fixed_xy
    d = np.linalg.norm(poses[:, :, None, :2] - fixed[None, None], axis=-1)
    assert np.all(d >= sc.workspace.min_clearance)


def test_impossible_problem_fails_fast_with_a_clear_error() -> None:
    sc = load_scene("cluttered")
    cons = LayoutConstraints.of(sc)
    crowded = replace(cons, min_clearance=0.5)  # eight objects 0.5 m apart cannot fit
    with pytest.raises(InfeasibleError, match="clearance"):
        crowded.sample(10, np.random.default_rng(0), max_draws=200_000)

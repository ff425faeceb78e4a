"""The streaming observer: recomputation, invariances, commit rule, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.core.geometry import Pose
from legws_daemon.core.goals import GoalSet
from legws_daemon.core.observer import IntentObserver, posterior_of_path
from legws_daemon.core.params import Params
from legws_daemon.errors import InputError

DOWN = [0.0, 1.0, 0.0, 0.0]


def make_goals(rng: np.random.Generator, m: int, x0: Pose | None = None) -> GoalSet:
    x0 = x0 or Pose(np.array([0.55, 0.0, 0.30]), np.array(DOWN))
    pos = np.column_stack(
        [rng.uniform(0.3, 0.85, m), rng.uniform(-0.45, 0.45, m), rng.uniform(0, 0.1, m)]
    )
    q = rng.normal(size=(m, 4))
    return GoalSet.build([f"g{i}" for i in range(m)], pos, q, x0, rng.integers(0, 4, m))


def random_path(rng: np.random.Generator, start: np.ndarray, n: int) -> np.ndarray:
    return start + np.cumsum(rng.normal(scale=0.004, size=(n, 3)), axis=0)


seeds = st.integers(0, 2**32 - 1)
forms = st.sampled_from(["dragan", "ratio"])


@settings(max_examples=60, deadline=None)
@given(seeds, st.integers(2, 10), st.integers(1, 200), forms)
def test_streaming_equals_recomputation(seed: int, m: int, n: int, cost: str) -> None:
    rng = np.random.default_rng(seed)
    goals = make_goals(rng, m)
    params = Params(cost=cost)  # type: ignore[arg-type]
    obs = IntentObserver(goals, params)
    path = random_path(rng, goals.x0.position, n)
    for p in path:
        post = obs.update(p, goals.x0.quaternion)
    np.testing.assert_allclose(post, posterior_of_path(goals, params, path), rtol=1e-9, atol=1e-12)
    assert obs.path_length == pytest.approx(
        np.linalg.norm(np.diff(np.vstack([goals.x0.position, path]), axis=0), axis=1).sum()
    )


@settings(max_examples=60, deadline=None)
@given(seeds, st.integers(2, 10), forms)
def test_posterior_sums_to_one_and_is_order_and_translation_invariant(
    seed: int, m: int, cost: str
) -> None:
    rng = np.random.default_rng(seed)
    goals = make_goals(rng, m)
    params = Params(cost=cost)  # type: ignore[arg-type]
    path = random_path(rng, goals.x0.position, 50)
    post = posterior_of_path(goals, params, path)
    assert post.sum() == pytest.approx(1.0)
    assert np.all(post >= 0)

    perm = rng.permutation(m)
    shuffled = GoalSet.build(
        [goals.names[i] for i in perm],
        goals.positions[perm],
        goals.quaternions[perm],
        goals.x0,
        goals.symmetry[perm],
    )
    obs = IntentObserver(shuffled, params)
    for p in path:
        post_perm = obs.update(p)
    np.testing.assert_allclose(post_perm, post[perm], rtol=1e-9, atol=1e-12)

    shift = rng.uniform(-1, 1, 3)
    moved = GoalSet.build(
        goals.names,
        goals.positions + shift,
        goals.quaternions,
        Pose(goals.x0.position + shift, goals.x0.quaternion),
        goals.symmetry,
    )
    np.testing.assert_allclose(
        posterior_of_path(moved, params, path + shift), post, rtol=1e-7, atol=1e-10
    )


@pytest.mark.parametrize("m", [2, 3, 5, 8])
def test_moving_straight_to_a_goal_commits_to_it(m: int) -> None:
    # goals spread on a circle of radius 0.45 m just below x0, all with x0's orientation
    x0 = Pose(np.array([0.55, 0.0, 0.10]), np.array(DOWN))
    ang = 2 * np.pi * np.arange(m) / m
    pos = np.column_stack([0.55 + 0.45 * np.cos(ang), 0.45 * np.sin(ang), np.zeros(m)])
    goals = GoalSet.build([f"g{i}" for i in range(m)], pos, [DOWN] * m, x0)
    target = m // 2
    obs = IntentObserver(goals, Params())
    p = goals.x0.position.copy()
    for _ in range(400):
        step = goals.positions[target] - p
        dist = np.linalg.norm(step)
        if dist < 1e-4:
            break
        p = p + step / dist * min(0.0025, dist)
        obs.update(p)
        if obs.committed is not None:
            break
    assert obs.committed == target
    assert obs.posterior[target] >= 0.9
    assert obs.commit_tick is not None and obs.commit_tick == obs.ticks


def test_commit_is_first_crossing_and_sticks_until_reset() -> None:
    x0 = Pose(np.array([0.0, 0.0, 0.3]), np.array(DOWN))
    goals = GoalSet.build(["a", "b"], [[0.3, 0.2, 0.0], [0.3, -0.2, 0.0]], [DOWN, DOWN], x0)
    obs = IntentObserver(goals, Params())
    p = x0.position.copy()
    first = None
    for k in range(200):
        p = p + 0.0025 * (goals.positions[0] - p) / np.linalg.norm(goals.positions[0] - p)
        post = obs.update(p)
        if first is None and post.max() >= 0.9:
            first = k + 1
    assert obs.committed == 0 and obs.commit_tick == first
    # moving toward b afterwards does not change the commitment
    for _ in range(200):
        obs.update(p + np.array([0.0, -0.01, 0.0]))
    assert obs.committed == 0
    obs.reset()
    assert obs.committed is None and obs.path_length == 0.0 and obs.ticks == 0
    np.testing.assert_allclose(obs.posterior, [0.5, 0.5])


def test_commit_threshold_is_respected() -> None:
    x0 = Pose(np.array([0.0, 0.0, 0.3]), np.array(DOWN))
    goals = GoalSet.build(["a", "b"], [[0.3, 0.2, 0.0], [0.3, -0.2, 0.0]], [DOWN, DOWN], x0)
    ticks = {}
    for thresh in (0.6, 0.9, 0.95):
        obs = IntentObserver(goals, Params(p_thresh=thresh))
        p = x0.position.copy()
        while obs.committed is None and obs.ticks < 500:
            p = p + 0.0025 * (goals.positions[0] - p) / np.linalg.norm(goals.positions[0] - p)
            obs.update(p)
        ticks[thresh] = obs.commit_tick
    assert ticks[0.6] is not None and ticks[0.9] is not None and ticks[0.95] is not None
    assert ticks[0.6] < ticks[0.9] < ticks[0.95]


def test_orientation_matters_through_the_rotation_term() -> None:
    x0 = Pose(np.array([0.0, 0.0, 0.3]), np.array([1.0, 0, 0, 0]))
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    # two goals at mirrored positions; b is turned 90 degrees about z
    goals = GoalSet.build(
        ["a", "b"], [[0.2, 0.1, 0.0], [0.2, -0.1, 0.0]], [[1, 0, 0, 0], [c, 0, 0, s]], x0
    )
    obs = IntentObserver(goals, Params())
    p = np.array([0.05, 0.0, 0.25])
    plain = obs.update(p).copy()
    obs.reset()
    turned = obs.update(p, [c, 0, 0, s])
    # mirrored positions, orientation held: the rotation terms cancel, no preference
    np.testing.assert_allclose(plain, [0.5, 0.5])
    # turning the gripper to b's orientation is evidence for b
    assert turned[1] > 0.6


@pytest.mark.parametrize(
    ("position", "quaternion"),
    [
        ([np.nan, 0, 0], None),
        ([0, np.inf, 0], None),
        ([0, 0], None),
        ([0, 0, 0.2], [0, 0, 0, 0]),
        ([0, 0, 0.2], [np.nan, 1, 0, 0]),
    ],
)
def test_bad_input_is_rejected_and_state_is_unchanged(
    position: list[float], quaternion: list[float] | None
) -> None:
    x0 = Pose(np.array([0.0, 0.0, 0.3]), np.array(DOWN))
    goals = GoalSet.build(["a", "b"], [[0.3, 0.2, 0.0], [0.3, -0.2, 0.0]], [DOWN, DOWN], x0)
    obs = IntentObserver(goals, Params())
    obs.update([0.01, 0.01, 0.29])
    before = (obs.posterior, obs.path_length, obs.ticks)
    with pytest.raises(InputError):
        obs.update(position, quaternion)
    after = (obs.posterior, obs.path_length, obs.ticks)
    np.testing.assert_array_equal(before[0], after[0])
    assert before[1:] == after[1:]

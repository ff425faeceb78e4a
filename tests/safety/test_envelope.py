"""The safety envelope holds for any position and any command (property tests)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.errors import InputError
from legws_daemon.safety.envelope import Box, clamp_ee_velocity, clamp_joint_velocity

BOX = Box(np.array([0.2, -0.55, 0.0]), np.array([0.95, 0.55, 0.6]))
DT, V_MAX = 0.05, 0.05

anything = st.floats(allow_nan=True, allow_infinity=True, width=64)
finite = st.floats(-5, 5, allow_nan=False)
vectors = st.lists(anything, min_size=3, max_size=3)
positions = st.lists(st.floats(-1.5, 1.5), min_size=3, max_size=3)


@settings(max_examples=2000, deadline=None)
@given(positions, vectors)
def test_never_faster_than_v_max_never_out_of_the_box(p: list[float], v: list[float]) -> None:
    out = clamp_ee_velocity(p, v, DT, BOX, V_MAX)
    assert out.shape == (3,)
    assert np.all(np.isfinite(out))
    assert math.sqrt(float(out @ out)) <= V_MAX * (1 + 1e-12)
    pos = np.array(p)
    nxt = pos + out * DT
    if BOX.contains(pos):
        assert BOX.contains(nxt, tol=1e-9)
    for i in range(3):  # outside on an axis: never further out on it
        if pos[i] > BOX.upper[i]:
            assert out[i] <= 0.0
        if pos[i] < BOX.lower[i]:
            assert out[i] >= 0.0


@settings(max_examples=500, deadline=None)
@given(positions, st.lists(finite, min_size=3, max_size=3))
def test_inside_and_slow_commands_pass_unchanged(p: list[float], v: list[float]) -> None:
    pos = np.clip(np.array(p), BOX.lower + 0.01, BOX.upper - 0.01)
    vel = np.array(v)
    vel = vel / max(1.0, float(np.linalg.norm(vel)) / (0.9 * V_MAX))  # below v_max, < 2.3 mm/tick
    np.testing.assert_array_equal(clamp_ee_velocity(pos, vel, DT, BOX, V_MAX), vel)


@pytest.mark.parametrize(
    ("position", "velocity"),
    [
        ([0.5, 0.0, 0.3], [math.nan, 0.0, 0.0]),
        ([0.5, 0.0, 0.3], [0.0, math.inf, 0.0]),
        ([math.nan, 0.0, 0.3], [0.01, 0.0, 0.0]),
        ([0.5, 0.0, 0.3], [0.01, 0.0]),
        ([0.5, 0.0, 0.3], "fast"),
        ([0.5, 0.0, 0.3], None),
    ],
)
def test_bad_input_is_zero_velocity(position: list[float], velocity: object) -> None:
    np.testing.assert_array_equal(clamp_ee_velocity(position, velocity, DT, BOX, V_MAX), 0.0)


def test_stops_exactly_at_the_face() -> None:
    p = np.array([0.949, 0.0, 0.3])
    out = clamp_ee_velocity(p, [0.05, 0.0, 0.0], DT, BOX, V_MAX)
    assert p[0] + out[0] * DT == pytest.approx(0.95)


LOWER = np.array([-3.0, -3.8, -3.0, -3.0, -2.9, -2.9, -4.7])
UPPER = -LOWER
QDOT_MAX = np.array([1.74, 1.328, 1.957, 1.957, 3.485, 3.485, 4.545])


@settings(max_examples=1000, deadline=None)
@given(
    st.lists(st.floats(-5, 5), min_size=7, max_size=7),
    st.lists(anything, min_size=7, max_size=7),
)
def test_joint_commands_respect_speed_and_position_limits(q: list[float], qd: list[float]) -> None:
    out = clamp_joint_velocity(q, qd, DT, LOWER, UPPER, QDOT_MAX)
    assert np.all(np.isfinite(out))
    assert np.all(np.abs(out) <= QDOT_MAX * (1 + 1e-12))
    qq = np.array(q)
    nxt = qq + out * DT
    inside = (qq >= LOWER) & (qq <= UPPER)
    assert np.all(nxt[inside] <= UPPER[inside] + 1e-9)
    assert np.all(nxt[inside] >= LOWER[inside] - 1e-9)
    assert np.all(out[qq > UPPER] <= 0)
    assert np.all(out[qq < LOWER] >= 0)


def test_box_validates() -> None:
    with pytest.raises(InputError):
        Box(np.array([0.0, 0.0, 0.0]), np.array([1.0, -1.0, 1.0]))
    with pytest.raises(InputError):
        Box(np.array([0.0, math.nan, 0.0]), np.array([1.0, 1.0, 1.0]))

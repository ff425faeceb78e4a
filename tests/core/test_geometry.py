"""Quaternions, rotations and the SE(3) distance with grasp symmetry."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from legws_daemon.core.geometry import (
    Pose,
    axis_rotation,
    matrix_to_quat,
    normalize_quaternion,
    quat_to_matrix,
    rot_z,
    rotation_angle,
    se3_distance,
    symmetric_angle,
    yaw_quat,
)
from legws_daemon.errors import InputError

quats = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(
    lambda q: math.sqrt(sum(c * c for c in q)) > 0.1
)


def axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    return np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * axis])


@settings(max_examples=200, deadline=None)
@given(quats)
def test_quaternion_matrix_round_trip(q: list[float]) -> None:
    R = quat_to_matrix(q)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    back = matrix_to_quat(R)
    np.testing.assert_allclose(back, normalize_quaternion(q), atol=1e-9)


def test_mujoco_order_w_first() -> None:
    # 180 degrees about x: [w, x, y, z] = [0, 1, 0, 0] maps z to -z (gripper pointing down)
    np.testing.assert_allclose(quat_to_matrix([0, 1, 0, 0]), np.diag([1.0, -1.0, -1.0]), atol=1e-15)
    np.testing.assert_allclose(quat_to_matrix(axis_angle(np.array([0, 0, 1.0]), 0.3)), rot_z(0.3))


def test_normalize_rejects_zero_and_nan() -> None:
    with pytest.raises(InputError):
        normalize_quaternion([0, 0, 0, 0])
    with pytest.raises(InputError):
        normalize_quaternion([np.nan, 1, 0, 0])


@settings(max_examples=100, deadline=None)
@given(quats, st.floats(0, math.pi))
def test_rotation_angle_of_axis_angle(q: list[float], angle: float) -> None:
    R = quat_to_matrix(q)
    axis = np.array([0.3, -0.5, 0.8])
    R2 = R @ quat_to_matrix(axis_angle(axis, angle))
    assert rotation_angle(R, R2) == pytest.approx(angle, abs=1e-6)


@settings(max_examples=100, deadline=None)
@given(quats, quats, st.integers(1, 6))
def test_discrete_symmetry_is_min_over_equivalents(
    q1: list[float], q2: list[float], n: int
) -> None:
    R, G = quat_to_matrix(q1), quat_to_matrix(q2)
    brute = min(rotation_angle(R, G @ rot_z(2 * math.pi * k / n)) for k in range(n))
    assert symmetric_angle(R, G, n) == pytest.approx(brute, abs=1e-7)
    assert symmetric_angle(R, G, n) <= rotation_angle(R, G) + 1e-6


@settings(max_examples=100, deadline=None)
@given(quats, quats)
def test_continuous_symmetry_is_angle_between_approach_axes(
    q1: list[float], q2: list[float]
) -> None:
    R, G = quat_to_matrix(q1), quat_to_matrix(q2)
    cos = float(np.clip(R[:, 2] @ G[:, 2], -1, 1))
    assert symmetric_angle(R, G, 0) == pytest.approx(math.acos(cos), abs=1e-6)
    dense = min(rotation_angle(R, G @ rot_z(phi)) for phi in np.linspace(0, 2 * math.pi, 3601))
    assert symmetric_angle(R, G, 0) == pytest.approx(dense, abs=2e-3)


def test_symmetric_equivalents_are_at_zero_angle() -> None:
    G = quat_to_matrix([0.2, 0.9, -0.1, 0.3])
    assert symmetric_angle(G @ rot_z(math.pi), G, 2) == pytest.approx(0.0, abs=1e-7)
    assert symmetric_angle(G @ rot_z(math.pi / 2), G, 4) == pytest.approx(0.0, abs=1e-7)
    assert symmetric_angle(G @ rot_z(1.234), G, 0) == pytest.approx(0.0, abs=1e-7)
    assert symmetric_angle(G @ rot_z(math.pi), G, 1) == pytest.approx(math.pi)
    assert symmetric_angle(G @ rot_z(math.pi / 2), G, 2) == pytest.approx(math.pi / 2)


def test_batched_symmetry_broadcasts() -> None:
    R = quat_to_matrix([0, 1, 0, 0])
    G = np.stack([R @ rot_z(a) for a in (0.5, 2.0, 3.0)])
    got = symmetric_angle(R, G, np.array([1, 2, 0]))
    assert got == pytest.approx([0.5, math.pi - 2.0, 0.0], abs=1e-7)


def test_se3_distance_adds_weighted_angle() -> None:
    R = np.eye(3)
    G = rot_z(0.5)
    d = se3_distance([0, 0, 0], R, [0.3, 0.4, 0], G, 1, 0.04)
    assert d == pytest.approx(0.5 + 0.04 * 0.5)
    assert se3_distance([0, 0, 0], R, [0.3, 0.4, 0], G @ rot_z(math.pi), 2, 0.04) == pytest.approx(
        0.52
    )


def test_pose_validates() -> None:
    p = Pose(np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.0, 0.0, -2.0]))
    np.testing.assert_allclose(p.quaternion, [0, 0, 0, 1])
    with pytest.raises(InputError):
        Pose(np.array([1.0, np.nan, 3.0]), np.array([1.0, 0, 0, 0]))
    with pytest.raises(InputError):
        Pose(np.array([1.0, 3.0]), np.array([1.0, 0, 0, 0]))


@given(st.lists(st.floats(-1, 1), min_size=3, max_size=3), st.floats(-7.0, 7.0))
def test_axis_rotation_turns_by_the_angle_about_the_axis(axis: list[float], angle: float) -> None:
    a = np.array(axis)
    assume(np.linalg.norm(a) > 0.1)
    a /= np.linalg.norm(a)
    R = axis_rotation(a, angle)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(R @ a, a, atol=1e-12)  # the axis stays put
    wrapped = abs((angle + np.pi) % (2 * np.pi) - np.pi)
    assert float(rotation_angle(R, np.eye(3))) == pytest.approx(wrapped, abs=1e-6)
    # about z it is rot_z; a batch of angles gives a batch of matrices
    np.testing.assert_allclose(axis_rotation([0, 0, 1], angle), rot_z(angle), atol=1e-12)
    batch = axis_rotation(a, np.array([angle, 0.0]))
    assert batch.shape == (2, 3, 3)
    np.testing.assert_allclose(batch[0], R, atol=1e-15)
    np.testing.assert_allclose(batch[1], np.eye(3), atol=1e-15)


@given(st.floats(-10.0, 10.0))
def test_yaw_quat_is_the_turn_about_z(yaw: float) -> None:
    q = yaw_quat(yaw)
    assert q.shape == (4,)
    np.testing.assert_allclose(quat_to_matrix(q), rot_z(yaw), atol=1e-12)

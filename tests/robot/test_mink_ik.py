"""mink's differential IK (``robot/mink_ik.py``) on the real MuJoCo Sawyer model.

Tracking (``J dq = twist`` and finite differences), exact joint limits (a hypothesis
property over twists up to 1000 m/s), zero and invalid commands, and a comparison with the
damped least-squares ``velocity_step`` away from and near the joint limits.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.arms import arm
from legws_daemon.errors import InputError, LegwsError
from legws_daemon.robot.kinematics import (
    LIMIT_MARGIN,
    home_configuration,
    rotation_error,
    velocity_step,
)
from legws_daemon.robot.mink_ik import MinkVelocityIK
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene

SAWYER = arm("sawyer")
JOINT_SPEED_LIMITS = np.array(SAWYER.speed_limits)
READY_POSTURE = np.array(SAWYER.ready_posture)

DT = 0.05  # the daemon's control period at 20 Hz
#: Random configurations stay this far inside the joint range (no position limit near).
INSET = 0.3
#: Configurations whose Jacobian's smallest singular value is below this are skipped where
#: the test needs the twist to be reachable without hitting a speed limit.
MIN_SIGMA = 0.05


@pytest.fixture(scope="module")
def world() -> World:
    return World(load_scene("desk"), visual=False)


@pytest.fixture(scope="module")
def ik(world: World) -> MinkVelocityIK:
    return MinkVelocityIK(world)


@pytest.fixture(scope="module")
def q_home(world: World) -> np.ndarray:
    scene = world.scene
    return home_configuration(world, scene.home.position, scene.home.rotation).q


def jacobian(world: World, q: np.ndarray) -> np.ndarray:
    world.set_q(q)
    return world.jacobian()


def well_conditioned(world: World, rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """``n`` random configurations away from joint limits and from singularities."""
    lo, hi = world.arm.lower + INSET, world.arm.upper - INSET
    out: list[np.ndarray] = []
    while len(out) < n:
        q = rng.uniform(lo, hi)
        if np.linalg.svd(jacobian(world, q), compute_uv=False)[-1] >= MIN_SIGMA:
            out.append(q)
    return out


def small_twist(rng: np.random.Generator) -> np.ndarray:
    """Up to 0.1 m/s and 0.3 rad/s per axis: teleoperation speeds."""
    return np.concatenate([rng.uniform(-0.1, 0.1, 3), rng.uniform(-0.3, 0.3, 3)])


def relative_error(J: np.ndarray, dq: np.ndarray, twist: np.ndarray) -> float:
    return float(np.linalg.norm(J @ dq - twist) / np.linalg.norm(twist))


def assert_within_limits(ik: MinkVelocityIK, q: np.ndarray, dq: np.ndarray, dt: float) -> None:
    """Speed limits, and after ``dt``: inside the margin band, or no further out than now."""
    assert np.all(np.abs(dq) <= ik.speed_limits)
    q_next = q + dq * dt
    assert np.all(q_next <= np.maximum(ik.upper, q) + 1e-12)
    assert np.all(q_next >= np.minimum(ik.lower, q) - 1e-12)


# --- (a), (b): tracking --------------------------------------------------------------
def test_joint_velocity_realises_the_twist_when_no_limit_is_active(
    world: World, ik: MinkVelocityIK
) -> None:
    rng = np.random.default_rng(0)
    errors = []
    for q in well_conditioned(world, rng, 60):
        twist = small_twist(rng)
        dq = ik.joint_velocity(q, twist, DT)
        assert np.all(np.abs(dq) < 0.95 * ik.speed_limits)  # no speed limit active
        errors.append(relative_error(jacobian(world, q), dq, twist))
    # left: the posture task's weight, and the twist's first-order effect on a pose target
    # reached along a straight line (|w| dt / 2)
    assert max(errors) < 0.01
    assert float(np.median(errors)) < 0.004


def test_integrating_dq_moves_the_ee_by_twist_dt(world: World, ik: MinkVelocityIK) -> None:
    rng = np.random.default_rng(1)
    periods = (0.04, 0.01, 0.0025)
    errors: dict[float, list[float]] = {dt: [] for dt in periods}
    for q in well_conditioned(world, rng, 30):
        twist = small_twist(rng)
        world.set_q(q)
        p0, R0 = world.ee_position(), world.ee_rotation().copy()
        for dt in periods:
            dq = ik.joint_velocity(q, twist, dt)
            world.set_q(q + dq * dt)
            moved = np.concatenate(
                [world.ee_position() - p0, rotation_error(R0, world.ee_rotation())]
            )
            errors[dt].append(
                float(np.linalg.norm(moved - twist * dt) / np.linalg.norm(twist * dt))
            )
    # a constant joint velocity over dt follows the twist to first order: the relative
    # error shrinks like dt (x4 from 0.04 s to 0.01 s), and is small at a fast rate
    ratios = np.array(errors[0.04]) / np.array(errors[0.01])
    assert float(np.median(ratios)) > 3.0
    assert max(errors[0.0025]) < 0.03
    assert float(np.median(errors[0.0025])) < 0.005


def test_the_redundancy_drifts_toward_the_posture_without_disturbing_the_ee(
    world: World, ik: MinkVelocityIK, q_home: np.ndarray
) -> None:
    q = q_home + np.array([0.3, 0.0, -0.4, 0.0, 0.3, 0.0, 0.0])
    twist = np.array([0.01, 0.0, 0.0, 0.0, 0.0, 0.0])
    dq = ik.joint_velocity(q, twist, DT)
    assert relative_error(jacobian(world, q), dq, twist) < 0.01
    before = np.linalg.norm((q - READY_POSTURE)[:6])
    after = np.linalg.norm((q + dq * DT - READY_POSTURE)[:6])
    assert after < before - 1e-3  # the null-space motion is toward the posture


# --- (c): exact limits ---------------------------------------------------------------
@settings(max_examples=200, deadline=None)
@given(
    joint=st.integers(0, 6),
    side=st.sampled_from([-1.0, 1.0]),
    # distance inside the margin band; negative: in the margin, down to the hardware stop
    depth=st.floats(-LIMIT_MARGIN, 0.05),
    push=st.floats(0.0, 1000.0),
    other=st.lists(st.floats(-1000.0, 1000.0), min_size=6, max_size=6),
    dt=st.sampled_from([0.01, DT]),
)
def test_limits_hold_near_a_joint_limit_for_any_twist(
    world: World,
    ik: MinkVelocityIK,
    q_home: np.ndarray,
    joint: int,
    side: float,
    depth: float,
    push: float,
    other: list[float],
    dt: float,
) -> None:
    q = q_home.copy()
    q[joint] = ik.upper[joint] - depth if side > 0 else ik.lower[joint] + depth
    # the EE twist this joint alone would make, pushing it toward its limit, plus any twist
    column = jacobian(world, q)[:, joint]
    twist = side * push * column / np.linalg.norm(column) + np.array(other)
    dq = ik.joint_velocity(q, twist, dt)
    assert_within_limits(ik, q, dq, dt)
    # never past the hardware stop (at it, with depth -LIMIT_MARGIN, it is held there)
    assert world.arm.lower[joint] <= q[joint] + dq[joint] * dt <= world.arm.upper[joint]


def test_a_joint_pushed_into_its_limit_stops_at_the_band(
    world: World, ik: MinkVelocityIK, q_home: np.ndarray
) -> None:
    joint = 3
    q = q_home.copy()
    q[joint] = ik.upper[joint] - 0.01
    column = jacobian(world, q)[:, joint]
    dq = ik.joint_velocity(q, 0.5 * column / np.linalg.norm(column), DT)
    reached = q[joint] + dq[joint] * DT
    assert reached <= ik.upper[joint]
    assert reached > ik.upper[joint] - 0.001  # uses the room it has (95 % per step)


def test_a_joint_at_its_hardware_stop_is_held_not_yanked_in(
    world: World, ik: MinkVelocityIK, q_home: np.ndarray
) -> None:
    # outside the margin band: the QP stays feasible even at 100 Hz, where pulling the joint
    # back into the band within one period would exceed its speed limit
    joint = 1
    q = q_home.copy()
    q[joint] = world.arm.upper[joint]
    column = jacobian(world, q)[:, joint]
    for dt in (0.01, DT):
        dq = ik.joint_velocity(q, 0.2 * column / np.linalg.norm(column), dt)
        assert dq[joint] <= 0.0
        assert_within_limits(ik, q, dq, dt)


# --- (d), (e): zero and invalid commands ---------------------------------------------
def test_a_zero_twist_gives_exactly_zero(
    world: World, ik: MinkVelocityIK, q_home: np.ndarray
) -> None:
    beyond = q_home.copy()
    beyond[1] = world.arm.upper[1]  # even where the posture or a limit could pull
    far = q_home + 0.5  # far from the posture
    for q in (q_home, beyond, far):
        for zero in (np.zeros(6), -np.zeros(6), [0, 0, 0, 0, 0, 0]):
            dq = ik.joint_velocity(q, zero, DT)
            assert dq.shape == (7,)
            np.testing.assert_array_equal(dq, np.zeros(7))


@pytest.mark.parametrize(
    ("q", "twist", "dt", "field"),
    [
        (None, [np.nan, 0, 0, 0, 0, 0], DT, "twist"),
        (None, [0, 0, 0, 0, 0, np.inf], DT, "twist"),
        (None, [0.01, 0, 0], DT, "twist"),
        ([0.0] * 6 + [np.nan], [0.01, 0, 0, 0, 0, 0], DT, "q"),
        ([0.0] * 6, [0.01, 0, 0, 0, 0, 0], DT, "q"),
        (None, [0.01, 0, 0, 0, 0, 0], 0.0, "dt"),
        (None, [0.01, 0, 0, 0, 0, 0], -DT, "dt"),
        (None, [0.01, 0, 0, 0, 0, 0], float("nan"), "dt"),
    ],
)
def test_non_finite_or_misshapen_input_is_refused(
    ik: MinkVelocityIK,
    q_home: np.ndarray,
    q: list[float] | None,
    twist: list[float],
    dt: float,
    field: str,
) -> None:
    with pytest.raises(InputError, match=rf"^{field}: ") as info:
        ik.joint_velocity(q_home if q is None else q, twist, dt)
    assert info.value.field == field


def test_a_bad_posture_is_refused(world: World) -> None:
    with pytest.raises(LegwsError, match="posture must be 7 finite"):
        MinkVelocityIK(world, posture=[0.0] * 6)
    with pytest.raises(LegwsError, match="posture_cost"):
        MinkVelocityIK(world, posture_cost=0.0)


def test_the_world_is_not_moved(world: World, ik: MinkVelocityIK, q_home: np.ndarray) -> None:
    world.set_q(q_home)
    ik.joint_velocity(q_home + 0.1, [0.05, 0, 0, 0, 0, 0], DT)
    np.testing.assert_array_equal(world.q, q_home)


# --- (f): against velocity_step ------------------------------------------------------
def dls_joint_velocity(world: World, q: np.ndarray, twist: np.ndarray) -> np.ndarray:
    """What the sawyer adapter sent before: one ``velocity_step``, as a joint velocity."""
    world.set_q(q)
    velocity_step(world, twist, DT)
    return np.asarray(np.clip((world.q - q) / DT, -JOINT_SPEED_LIMITS, JOINT_SPEED_LIMITS))


def tracking_errors(
    world: World,
    ik: MinkVelocityIK,
    cases: list[tuple[np.ndarray, np.ndarray]],
    check: Callable[[np.ndarray, np.ndarray], None],
) -> tuple[np.ndarray, np.ndarray]:
    mink_err, dls_err = [], []
    for q, twist in cases:
        J = jacobian(world, q)
        dq = ik.joint_velocity(q, twist, DT)
        check(q, dq)
        mink_err.append(relative_error(J, dq, twist))
        dls_err.append(relative_error(J, dls_joint_velocity(world, q, twist), twist))
    return np.array(mink_err), np.array(dls_err)


def test_both_track_the_twist_away_from_limits(world: World, ik: MinkVelocityIK) -> None:
    rng = np.random.default_rng(2)
    cases = [(q, small_twist(rng)) for q in well_conditioned(world, rng, 60)]
    mink_err, dls_err = tracking_errors(world, ik, cases, lambda q, dq: None)
    assert np.median(mink_err) < 0.005
    assert np.median(dls_err) < 0.02  # its damping (0.02) costs it a little tracking
    assert np.median(mink_err) < np.median(dls_err)


def test_near_limits_mink_tracks_better_than_blocking_joints(
    world: World, ik: MinkVelocityIK
) -> None:
    """A joint a few mrad inside its band, the twist pushing it outward: velocity_step stops
    that joint for the whole step, the QP uses the room left and the other joints."""
    rng = np.random.default_rng(3)
    lo, hi = world.arm.lower + INSET, world.arm.upper - INSET
    cases: list[tuple[np.ndarray, np.ndarray]] = []
    while len(cases) < 80:
        q = rng.uniform(lo, hi)
        joint, side = int(rng.integers(7)), float(rng.choice([-1.0, 1.0]))
        depth = rng.uniform(0.0, 0.03)
        q[joint] = ik.upper[joint] - depth if side > 0 else ik.lower[joint] + depth
        J = jacobian(world, q)
        if np.linalg.svd(J, compute_uv=False)[-1] < MIN_SIGMA:
            continue
        push = side * J[:, joint] / np.linalg.norm(J[:, joint])
        cases.append((q, 0.1 * push + rng.normal(0.0, 0.01, 6)))

    def check(q: np.ndarray, dq: np.ndarray) -> None:
        assert_within_limits(ik, q, dq, DT)

    mink_err, dls_err = tracking_errors(world, ik, cases, check)
    assert np.median(mink_err) < 0.01
    assert mink_err.mean() < 0.5 * dls_err.mean()
    assert np.all(mink_err <= dls_err + 0.01)


def test_speed_limited_mink_tracks_at_least_as_well_as_uniform_scaling(
    world: World, ik: MinkVelocityIK
) -> None:
    """Twists of 1-3 m/s: every joint velocity would pass its limit. velocity_step scales
    its answer down uniformly (a feasible point of the QP); the QP's optimum is no worse,
    and per-joint clipping of an unconstrained answer would be (it bends the motion)."""
    rng = np.random.default_rng(4)
    cases = []
    for q in well_conditioned(world, rng, 80):
        twist = small_twist(rng)
        twist *= rng.uniform(1.0, 3.0) / np.linalg.norm(twist[:3])
        world.set_q(q)
        if velocity_step(world, twist, DT).scale < 0.9:  # speed-limited by 10 % or more
            cases.append((q, twist))
    assert len(cases) >= 40

    def check(q: np.ndarray, dq: np.ndarray) -> None:
        assert_within_limits(ik, q, dq, DT)
        assert np.any(np.isclose(np.abs(dq), ik.speed_limits))  # a speed limit is active

    mink_err, dls_err = tracking_errors(world, ik, cases, check)
    assert np.all(mink_err <= dls_err + 1e-3)
    assert mink_err.mean() < 0.8 * dls_err.mean()

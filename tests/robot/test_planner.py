"""The motion planner on the real MuJoCo model: its approach reaches every desk grasp from
home without touching anything but the target, and refuses what is infeasible."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from legws_daemon.core.geometry import symmetric_angle
from legws_daemon.errors import InfeasibleError
from legws_daemon.robot.kinematics import small_rotation_error, velocity_step
from legws_daemon.robot.motion import BOX_MARGIN, JointMove, Move
from legws_daemon.robot.planner import (
    LATER_BOX_CLEARANCE,
    VIA_MIN_STEP,
    MotionPlanner,
    _off_the_faces,
)
from legws_daemon.robot.world import World
from legws_daemon.safety.envelope import Box
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import ObjectPose

BOX = Box(np.array([0.2, -0.55, 0.0]), np.array([0.95, 0.7, 0.6]))


@pytest.fixture(scope="module")
def planner() -> MotionPlanner:
    sc = load_scene("desk")
    p = MotionPlanner(World(sc), sc.home, BOX)
    p.set_layout(sc.default_layout())
    return p


def execute(w: World, moves: list[JointMove | Move]) -> None:
    """An ideal executor: joint moves exactly, Cartesian moves by velocity control."""
    for m in moves:
        if isinstance(m, JointMove):
            w.set_q(m.q)
            continue
        for _ in range(400):
            d = m.position - w.ee_position()
            if np.linalg.norm(d) < 5e-4:
                break
            v = 2.0 * d
            v *= min(1.0, 0.1 / max(float(np.linalg.norm(v)), 1e-12))
            twist = np.concatenate([v, 2.0 * small_rotation_error(w.ee_rotation(), m.rotation)])
            velocity_step(w, twist, 0.05)


@pytest.mark.parametrize("name", ["white_mug", "black_stapler", "maroon_pen_cup"])
def test_the_approach_reaches_the_grasp_pose(planner: MotionPlanner, name: str) -> None:
    sc = planner.world.scene
    g = sc.goal_set()
    i = g.index(name)
    check = planner.check(name, g.positions[i], g.rotations[i], int(g.symmetry[i]))
    assert check.feasible, check.reason
    assert planner.check(name, g.positions[i], g.rotations[i], int(g.symmetry[i])) is check
    w = planner.world.twin()
    w.set_q(planner.q_home)
    start = (w.ee_position(), w.ee_rotation())
    moves = planner.approach(
        check, g.positions[i], start=start, q=planner.q_home, carry_height=0.2, box=BOX
    )
    labels = [m.label for m in moves]
    assert labels[-3:] == ["carry", "approach", "reach"]
    # the joint-space move was checked: clear of the table, the box and other objects
    carry = moves[labels.index("carry")]
    assert isinstance(carry, JointMove)
    assert planner._blocked(planner.q_home, carry.q, BOX, frozenset({name})) is None
    reach = moves[-1]
    assert isinstance(reach, Move) and reach.floor == pytest.approx(g.positions[i][2] - 0.004)
    execute(w, [m for m in moves if isinstance(m, JointMove | Move)])
    assert np.linalg.norm(w.ee_position() - g.positions[i]) < 1e-3
    assert symmetric_angle(w.ee_rotation(), g.rotations[i], g.symmetry[i]) < 0.02
    assert w.arm_contacts(ignore=frozenset({name})) == []


def test_an_infeasible_grasp_is_refused_with_its_reason(planner: MotionPlanner) -> None:
    sc = planner.world.scene
    mug = sc.poses()["white_mug"]
    blocked = sc.default_layout() | {"black_stapler": ObjectPose(mug.x - 0.13, mug.y, np.pi / 2)}
    planner.set_layout(blocked)
    try:
        g = sc.goal_set(blocked)
        i = g.index("white_mug")
        check = planner.check("white_mug", g.positions[i], g.rotations[i], int(g.symmetry[i]))
        assert not check.feasible
        with pytest.raises(InfeasibleError, match="white_mug"):
            planner.approach(check, g.positions[i], start=(g.x0.position, g.x0.rotation),
                             q=planner.q_home, carry_height=0.2, box=BOX)  # fmt: skip
    finally:
        planner.set_layout(sc.default_layout())


def test_a_withdrawal_keeps_its_orientation_and_leaves_a_clear_way_or_is_none(
    planner: MotionPlanner,
) -> None:
    """From home to home there is nowhere to withdraw to; from a configuration off to the
    side, a withdrawal is a straight move at the orientation the arm has, inside the box,
    toward home, from whose IK the joint-space way home is clear."""
    home = planner.q_home
    assert planner.withdraw(home, home, BOX) is None
    w = planner.world
    side = planner._near(np.array([0.35, 0.45, 0.3]), w.ee_rotation(), home)
    assert side is not home  # reachable
    w.set_q(side)
    p0, R0 = w.ee_position(), w.ee_rotation()
    moves = planner.withdraw(side, home, BOX)
    assert moves is not None and len(moves) == 1
    move = moves[0]
    assert move.label == "withdraw" and move.optional
    np.testing.assert_allclose(move.rotation, R0)
    assert np.all(move.position >= BOX.lower) and np.all(move.position <= BOX.upper)
    w.set_q(home)
    to_home = w.ee_position() - p0
    assert float((move.position - p0)[:2] @ to_home[:2]) > 0  # toward home
    q = planner._near(move.position, R0, side)
    assert planner.joint_path(q, home, BOX) is not None  # (raises when there is no way)
    np.testing.assert_allclose(w.ee_position(), planner.home_position, atol=1e-3)  # left home


BOX = Box(np.array([0.2, -0.55, 0.0]), np.array([0.95, 0.7, 0.6]))
_coord = st.floats(-0.02, 0.02)


@given(
    face=st.sampled_from([(0, 0), (0, 1), (1, 0), (1, 1)]),
    off=st.floats(-0.99 * BOX_MARGIN, 0.99 * BOX_MARGIN),
    along=st.floats(-0.2, 0.2),
    z=st.floats(0.05, 0.5),
    depth=st.floats(0.02, 0.1),
    slant=_coord,
)
def test_a_pre_pose_on_a_side_face_is_pulled_in_toward_the_grasp(
    face: tuple[int, int], off: float, along: float, z: float, depth: float, slant: float
) -> None:
    """Within BOX_MARGIN of a side face (in or out) the pre-pose moves along the line to the
    grasp to BOX_MARGIN inside; the grasp itself stands inside the margin."""
    axis, side = face
    bound = BOX.lower if side == 0 else BOX.upper
    inward = 1.0 if side == 0 else -1.0
    pre = np.array([0.5, 0.1, z])
    pre[axis] = bound[axis] + inward * off
    pre[1 - axis] += along
    goal = pre.copy()
    goal[axis] = bound[axis] + inward * (BOX_MARGIN + depth)
    goal[1 - axis] += slant
    out = _off_the_faces(pre, goal, BOX)
    assert abs(out[axis] - (bound[axis] + inward * BOX_MARGIN)) < 1e-9  # on the margin
    t = (out - pre) @ (goal - pre) / ((goal - pre) @ (goal - pre))
    np.testing.assert_allclose(out, pre + t * (goal - pre), atol=1e-12)  # on the segment
    assert 0.0 < t < 1.0


@given(
    x=st.floats(0.2 + BOX_MARGIN, 0.95 - BOX_MARGIN),
    y=st.floats(-0.55 + BOX_MARGIN, 0.7 - BOX_MARGIN),
)
def test_a_pre_pose_off_the_faces_is_left_where_it_is(x: float, y: float) -> None:
    pre = np.array([x, y, 0.3])
    goal = np.array([0.5, 0.1, 0.2])
    np.testing.assert_array_equal(_off_the_faces(pre, goal, BOX), pre)
    # farther out than the margin: left to the joint-space check (it refuses the way)
    far = np.array([0.2 - 2 * BOX_MARGIN, y, 0.3])
    np.testing.assert_array_equal(_off_the_faces(far, goal, BOX), far)
    # a grasp on a face itself: nothing to pull toward
    edge = np.array([0.2 + 0.5 * BOX_MARGIN, 0.1, 0.2])
    on = np.array([0.2 + 0.2 * BOX_MARGIN, y, 0.3])
    np.testing.assert_array_equal(_off_the_faces(on, edge, BOX), on)


def _swing(planner: MotionPlanner, a: float, b: float) -> tuple[np.ndarray, np.ndarray]:
    """Home's configuration with the base turned by ``a`` and by ``b``: a joint line between
    them carries the EE along an arc, farthest out (in x) where the base angle is home's."""
    q0, q1 = planner.q_home.copy(), planner.q_home.copy()
    q0[0] += a
    q1[0] += b
    return q0, q1


def _far_x(planner: MotionPlanner) -> float:
    w = planner.world
    w.set_q(planner.q_home)
    return float(w.ee_position()[0])


def test_a_joint_line_that_grazes_a_face_is_blocked_and_one_with_clearance_is_not(
    planner: MotionPlanner,
) -> None:
    """The arc's ends stand ~5 cm inside x's upper face and its farthest point, home's, lies
    midway between two of the line's 15 samples (0.17 mm beyond them): 0.4 mm from the face
    it is blocked (the envelope would cut the arm's step there to nothing; the samples alone
    stand 0.57 mm inside), 0.6 mm from it clear."""
    everything = frozenset(planner.world.scene.objects)
    q0, q1 = _swing(planner, -0.375, 0.325)
    x = _far_x(planner)
    for clearance, clear in ((0.0004, False), (0.0006, True)):
        box = Box(BOX.lower, np.array([x + clearance, BOX.upper[1], BOX.upper[2]]))
        why = planner._blocked(q0, q1, box, everything)
        assert (why is None) == clear, why
        if not clear:
            assert why == "comes within 0.5 mm of the workspace box"
    planner.world.set_q(planner.q_home)


def test_a_joint_line_may_end_closer_to_a_face_than_the_clearance(
    planner: MotionPlanner,
) -> None:
    """From the face (1 mm inside) and back to it: the ends' own clearance is the bound."""
    everything = frozenset(planner.world.scene.objects)
    q_face, q_off = _swing(planner, 0.0, 0.35)
    x = _far_x(planner)
    box = Box(BOX.lower, np.array([x + 0.001, BOX.upper[1], BOX.upper[2]]))
    assert planner._blocked(q_face, q_off, box, everything) is None
    assert planner._blocked(q_off, q_face, box, everything) is None
    outside = Box(BOX.lower, np.array([x - 0.001, BOX.upper[1], BOX.upper[2]]))
    assert planner._blocked(q_off, q_face, outside, everything) == "leaves the workspace box"
    planner.world.set_q(planner.q_home)


def test_a_line_the_arm_takes_later_is_planned_with_more_room(planner: MotionPlanner) -> None:
    """A via's onward line is checked again from where the arm really reaches the via (within
    its tolerance): planned with 2 mm, it still passes the 0.5 mm check from there. The arc
    1 mm inside the face is clear now and not clear as a later line."""
    everything = frozenset(planner.world.scene.objects)
    q0, q1 = _swing(planner, -0.375, 0.325)
    box = Box(BOX.lower, np.array([_far_x(planner) + 0.001, BOX.upper[1], BOX.upper[2]]))
    assert planner._blocked(q0, q1, box, everything) is None
    why = planner._blocked(q0, q1, box, everything, LATER_BOX_CLEARANCE)
    assert why == f"comes within {LATER_BOX_CLEARANCE * 1000:g} mm of the workspace box"
    planner.world.set_q(planner.q_home)


@given(st.floats(0.0, 0.1), st.floats(0.0, 0.1))
def test_a_via_at_either_end_of_its_move_is_no_via(d0: float, d1: float) -> None:
    q0, q1 = np.zeros(7), np.full(7, 1.0)
    q = q0.copy()
    q[3] += d0
    apart = MotionPlanner._apart(q, q0, q1)
    assert apart == (d0 >= VIA_MIN_STEP)
    r = q1.copy()
    r[2] -= d1
    assert MotionPlanner._apart(r, q0, q1) == (d1 >= VIA_MIN_STEP)


def test_via_never_offers_where_the_arm_already_is(
    planner: MotionPlanner, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every IK of a via candidate lands by the arm (what an end already at the box's ceiling
    gives): none is offered, though the line from there may pass (the arm would be sent to
    where it stands, find the line blocked again, and be sent there again)."""
    everything = frozenset(planner.world.scene.objects)
    q0, q1 = _swing(planner, -0.375, 0.325)
    box = Box(BOX.lower, np.array([_far_x(planner) + 0.0004, BOX.upper[1], BOX.upper[2]]))
    assert planner._blocked(q0, q1, box, everything) is not None
    monkeypatch.setattr(planner, "_near", lambda position, rotation, seed: q0 + 1e-3)
    monkeypatch.setattr(planner, "_seeds", [q0 + 2e-3])
    R0, R1 = planner._rotation_at(q0), planner._rotation_at(q1)
    assert planner._via(q0, q1, R0, R1, box, everything) is None
    planner.world.set_q(planner.q_home)

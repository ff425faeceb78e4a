"""Issue 7 §2: the safety envelope holds for any sequence of inputs and states.

A hypothesis state machine drives the real stand-in (:class:`SimAdapter`) and the
controller on it with random sequences: EE velocity commands of any value (NaN, infinities,
huge, the wrong shape) with any orientation to hold, joystick ticks, stale and missing
input, the gripper, objects moved, operator commands and tracker poses. After every step:
the EE is inside the workspace box (1e-6 m), the last command sent is finite and at most
``v_max``, every joint is within its limits, and stale or missing input sent exactly zero
and moved nothing. Joint velocity commands (the assistance's joint-space moves) of any
value keep the joints' limits and the EE's speed.

The real arm's mapping (:class:`MinkVelocityIK`, used by the ``sawyer`` adapter) is checked
for arbitrary configurations and twists: joint speeds within ``JOINT_SPEED_LIMITS``, no joint
carried past its limit, what the ``sawyer`` adapter sends being exactly the IK's answer
(``tests/sim/test_mink_ik.py`` covers twists up to 1000 m/s near one limit from the home
posture; here every joint anywhere in its range or at a stop, twists up to 1e6).
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, precondition, rule

from legws_daemon.arms import arm
from legws_daemon.core.geometry import quat_to_matrix
from legws_daemon.errors import InfeasibleError, InputError, LegwsError
from legws_daemon.formats.messages import CommandRequest
from legws_daemon.robot.kinematics import LIMIT_MARGIN, home_configuration
from legws_daemon.robot.mink_ik import MinkVelocityIK
from legws_daemon.robot.world import World
from legws_daemon.safety.envelope import clamp_ee_velocity
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import ObjectPose
from tests.autonomy.rig import operator_command
from tests.reliability.helpers import (
    TALLIES,
    Rig,
    Tally,
    check_command,
    check_envelope,
    expect,
)

SAWYER = arm("sawyer")
JOINT_SPEED_LIMITS = np.array(SAWYER.speed_limits)

# --- values --------------------------------------------------------------------------
anything = st.floats(allow_nan=True, allow_infinity=True)
huge = st.floats(-1e300, 1e300)
velocities: st.SearchStrategy[Any] = st.one_of(
    st.tuples(st.floats(-0.2, 0.2), st.floats(-0.2, 0.2), st.floats(-0.2, 0.2)).map(list),
    st.lists(st.one_of(anything, huge), min_size=3, max_size=3),
    st.lists(st.floats(-1.0, 1.0), max_size=5).filter(lambda v: len(v) != 3),
    st.sampled_from([None, "fast", [[0.1, 0.0, 0.0]], [1e308, 1e308, 1e308], [0.0, 0.0, 0.0]]),
)
joint_velocities: st.SearchStrategy[Any] = st.one_of(
    st.lists(st.floats(-5.0, 5.0), min_size=7, max_size=7),
    st.lists(st.one_of(anything, huge), min_size=7, max_size=7),
    st.lists(st.floats(-1.0, 1.0), max_size=9).filter(lambda v: len(v) != 7),
)
unit_quaternions = st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(
    lambda q: math.sqrt(sum(c * c for c in q)) > 1e-3
)
#: Orientations to hold: none, or any rotation.
rotations: st.SearchStrategy[Any] = st.one_of(
    st.none(),
    unit_quaternions.map(lambda q: quat_to_matrix(np.array(q) / np.linalg.norm(q))),
)
#: ... or something that is not a rotation (named; the matrices are in BAD_HOLDS).
holds = rotations | st.sampled_from(["nan", "inf", "huge", "scaled", "reflection", "shape"])
BAD_HOLDS: dict[str, Any] = {
    "nan": np.full((3, 3), np.nan),
    "inf": np.diag([np.inf, 1.0, 1.0]),
    "huge": np.full((3, 3), 1e300),
    "scaled": 2.0 * np.eye(3),
    "reflection": np.diag([1.0, 1.0, -1.0]),
    "shape": np.eye(4),
}
axes = st.tuples(*[st.floats(-1.0, 1.0)] * 3).map(
    lambda a: [x / max(1.0, math.sqrt(sum(c * c for c in a))) for x in a]
)
rare = st.sampled_from([False] * 9 + [True])
planar = st.builds(
    ObjectPose, st.floats(-1.0, 2.0), st.floats(-1.0, 1.0), st.floats(-math.pi, math.pi)
)

_RIG: list[Rig] = []


def shared_rig() -> Rig:
    """One controller for every run of the machine (the world compiles once, ~0.5 s)."""
    if not _RIG:
        _RIG.append(Rig())
    return _RIG[0]


class EnvelopeMachine(RuleBasedStateMachine):
    """Random sequences of commands, ticks, grips, layouts and operator commands."""

    def __init__(self) -> None:
        super().__init__()
        self.rig = shared_rig()
        self.tally = TALLIES.setdefault("envelope sequences", Tally())
        self.last_sent = np.zeros(3)

    @initialize()
    def start_at_home(self) -> None:
        """Each run: the arm at home, the gripper open, the task from its start."""
        rig = self.rig
        rig.adapter.grip(False)
        home = rig.c.scene.home
        home_configuration(rig.world, home.position, home.rotation)
        rig.c.load(rig.c.scene, None, None)
        rig.inbox.clear()
        self.tally.examples += 1

    def step(self, outcome: str) -> None:
        self.tally.payloads += 1
        self.tally.outcomes[outcome] += 1
        self.tally.ticks = self.rig.ticks
        self.tally.modes = self.rig.modes

    # --- the adapter directly -------------------------------------------------------
    @rule(velocity=velocities, hold=holds)
    def send_velocity(self, velocity: Any, hold: Any) -> None:
        adapter = self.rig.adapter
        bad_hold = isinstance(hold, str)
        R = BAD_HOLDS[hold] if bad_hold else hold
        before = adapter.read_state()
        box = adapter.envelope(before.ee_rotation)
        expected = clamp_ee_velocity(before.ee_position, velocity, adapter.dt, box, adapter.v_max)
        sent, error = expect(InputError, adapter.send_velocity, before, velocity, R)
        assert (error is not None) == bad_hold, (hold, error)
        if isinstance(error, InputError):
            # an orientation that is not a rotation is refused and nothing moves
            assert error.field == "hold"
            np.testing.assert_array_equal(adapter.read_state().q, before.q)
            self.step("send_velocity: bad hold refused")
            return
        assert sent is not None
        np.testing.assert_array_equal(sent, expected)  # what was sent is the clamp's answer
        check_command(adapter, before.ee_position, sent)
        self.last_sent = sent
        if not np.any(sent) and R is None:
            np.testing.assert_array_equal(adapter.read_state().q, before.q)
        self.step("send_velocity: " + ("zero" if not np.any(sent) else "moved"))

    @rule(
        direction=st.tuples(*[st.floats(-1.0, 1.0)] * 3),
        speed=st.sampled_from([0.01, 0.1, 1.0, 1e6]),
        hold=rotations,
        periods=st.integers(10, 100),
    )
    def push(
        self, direction: tuple[float, float, float], speed: float, hold: Any, periods: int
    ) -> None:
        """One command held for many periods: the arm reaches the faces of the box."""
        adapter = self.rig.adapter
        v = np.array(direction) * speed
        for _ in range(periods):
            state = adapter.read_state()
            sent = adapter.send_velocity(state, v, hold)
            check_command(adapter, state.ee_position, sent)
            check_envelope(adapter, sent)
        self.last_sent = sent
        self.step("push")

    @rule(qdot=joint_velocities, periods=st.integers(1, 40))
    def send_joint_velocity(self, qdot: Any, periods: int) -> None:
        """Joint commands (assistance's joint-space moves) of any value, held for a while:
        joints within their limits and speeds, the EE at most ``v_max`` fast (measured)
        and inside the box; anything invalid is zero and moves nothing."""
        adapter = self.rig.adapter
        world = self.rig.world
        valid = isinstance(qdot, list) and len(qdot) == 7 and all(map(math.isfinite, qdot))
        for _ in range(periods):
            before = adapter.read_state()
            sent = adapter.send_joint_velocity(before, qdot)
            assert sent.qdot.shape == (7,) and np.all(np.isfinite(sent.qdot))
            assert np.all(np.abs(sent.qdot) <= JOINT_SPEED_LIMITS * (1 + 1e-9))
            after = adapter.read_state()
            assert np.all(after.q >= world.arm.lower) and np.all(after.q <= world.arm.upper)
            moved = float(np.linalg.norm(after.ee_position - before.ee_position))
            assert moved <= 1.2 * adapter.v_max * adapter.dt + 1e-9, moved
            check_envelope(adapter, sent.ee_velocity)
            if not valid:
                np.testing.assert_array_equal(sent.qdot, 0.0)
                np.testing.assert_array_equal(after.q, before.q)
        self.last_sent = sent.ee_velocity
        self.step("send_joint_velocity: " + ("valid" if valid else "invalid, zero"))

    @rule(closed=st.booleans())
    def grip(self, closed: bool) -> None:
        q = self.rig.adapter.read_state().q
        self.rig.adapter.grip(closed)
        np.testing.assert_array_equal(self.rig.adapter.read_state().q, q)
        self.step("grip")

    @rule(poses=st.dictionaries(st.sampled_from(["white_mug", "black_stapler", "maroon_pen_cup"]),
                                planar, max_size=3))  # fmt: skip
    def place_objects(self, poses: dict[str, ObjectPose]) -> None:
        q = self.rig.adapter.read_state().q
        assert self.rig.adapter.place_objects(poses)
        np.testing.assert_array_equal(self.rig.adapter.read_state().q, q)
        self.step("place_objects")

    # --- through the controller ----------------------------------------------------
    @rule(stick=axes, cancel=rare, confirm=rare)
    def tick_with_input(self, stick: list[float], cancel: bool, confirm: bool) -> None:
        rig = self.rig
        taken = rig.offer(rig.joystick(stick, cancel=cancel, confirm=confirm)) is not None
        # not taken only while nobody holds the lease and the message does not steer
        steers = any(stick) or cancel or confirm
        assert taken or (rig.inbox.operator() is None and not steers)
        self.last_sent = rig.tick().command
        self.step("tick with input")

    @rule(periods=st.integers(1, 12))
    def tick_after_silence(self, periods: int) -> None:
        """No new message for a while: past the deadman timeout the input is stale."""
        rig = self.rig
        for _ in range(periods):
            rig.now += rig.dt
        stale = rig.inbox.latest(rig.now + rig.dt) is None
        rec = rig.tick()  # (stale input: zero and nothing moved, checked in the rig)
        if stale:
            assert rec.joystick is None
            np.testing.assert_array_equal(rec.command, np.zeros(3))
        self.last_sent = rec.command
        self.step("tick after silence" + (" (stale)" if stale else ""))

    @rule()
    def tick_without_input(self) -> None:
        rec = self.rig.tick_with(None)
        np.testing.assert_array_equal(rec.command, np.zeros(3))
        self.last_sent = rec.command
        self.step("tick without input")

    @rule(command=st.sampled_from(["stop", "reset", "status"]))
    def operator(self, command: str) -> None:
        request = CommandRequest.model_validate({"schema": 1, "command": command})
        # refused (the robot failing): an error reply, nothing else
        expect(LegwsError, operator_command, self.rig.c, request)
        self.step(f"operator {command}")

    @rule(poses=st.dictionaries(st.sampled_from(["white_mug", "black_stapler", "maroon_pen_cup"]),
                                planar, min_size=1, max_size=3))  # fmt: skip
    def tracker(self, poses: dict[str, ObjectPose]) -> None:
        self.rig.c.observe(poses)
        self.step("tracker poses")

    @precondition(lambda self: self.rig.c.mode == "idle")
    @rule()
    def restart(self) -> None:
        self.rig.restart_if_done()
        self.step("restart")

    @invariant()
    def inside_the_envelope(self) -> None:
        check_envelope(self.rig.adapter, self.last_sent)


TestEnvelopeSequences = EnvelopeMachine.TestCase
TestEnvelopeSequences.settings = settings(
    # 80 sequences in the suite; LEGWS_ENVELOPE_SEQUENCES for a longer search
    max_examples=int(os.environ.get("LEGWS_ENVELOPE_SEQUENCES", "80")),
    stateful_step_count=40,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
TestEnvelopeSequences = pytest.mark.slow(TestEnvelopeSequences)


# --- the real arm's mapping: mink's QP --------------------------------------------------
@pytest.fixture(scope="module")
def world() -> World:
    return World(load_scene("desk"), visual=False)


@pytest.fixture(scope="module")
def ik(world: World) -> MinkVelocityIK:
    return MinkVelocityIK(world)


fraction = st.floats(0.0, 1.0)
#: Twist sizes (m/s, rad/s); up to SOLVABLE the QP must always answer.
magnitude = st.sampled_from([1e-3, 0.05, 1.0, 100.0, 1e4, 1e6])
SOLVABLE = 1e4


@settings(max_examples=1500, deadline=None)
@given(
    position=st.lists(fraction, min_size=7, max_size=7),
    stops=st.lists(
        st.sampled_from([None, "lower", "upper", "band_lower", "band_upper"]),
        min_size=7,
        max_size=7,
    ),
    direction=st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6),
    size=magnitude,
    dt=st.sampled_from([0.01, 0.05]),
)
def test_mink_keeps_joint_speed_and_position_limits_from_any_configuration(
    world: World,
    ik: MinkVelocityIK,
    position: list[float],
    stops: list[str | None],
    direction: list[float],
    size: float,
    dt: float,
) -> None:
    lower, upper = world.arm.lower, world.arm.upper
    q = lower + np.array(position) * (upper - lower)
    at = {"lower": lower, "upper": upper, "band_lower": lower + LIMIT_MARGIN,
          "band_upper": upper - LIMIT_MARGIN}  # fmt: skip
    for j, stop in enumerate(stops):
        if stop is not None:
            q[j] = at[stop][j]
    twist = np.array(direction) * size
    try:
        dq = ik.joint_velocity(q, twist, dt)
    except InfeasibleError:
        # daqp gives up on some twists of 1e5 m/s (rad/s) and more (a few in a hundred):
        # nothing is sent and the daemon halts the arm. The adapter never asks for such a
        # twist (its velocity is clamped to v_max <= 2 m/s, its rotation to <= 2 rad/s).
        if size <= SOLVABLE:
            pytest.fail(f"no solution at q={q.tolist()} for twist {twist.tolist()}")
        return
    # what the sawyer adapter sends: the IK's answer within the bridge contract's limits
    sent = np.clip(dq, -JOINT_SPEED_LIMITS, JOINT_SPEED_LIMITS)
    np.testing.assert_array_equal(sent, dq)  # the clip is a no-op: the IK keeps them
    assert np.all(np.isfinite(dq))
    assert np.all(np.abs(dq) <= JOINT_SPEED_LIMITS)
    nxt = q + dq * dt
    assert np.all(nxt >= np.minimum(lower + LIMIT_MARGIN, q))  # never past the band ...
    assert np.all(nxt <= np.maximum(upper - LIMIT_MARGIN, q))  # ... or further out than now
    assert np.all(nxt >= lower)
    assert np.all(nxt <= upper)


@settings(max_examples=300, deadline=None)
@given(
    twist=st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6),
    bad=st.lists(st.sampled_from([math.nan, math.inf, -math.inf]), min_size=1, max_size=6),
    where=st.permutations(range(6)),
)
def test_mink_refuses_non_finite_twists(
    ik: MinkVelocityIK, twist: list[float], bad: list[float], where: list[int]
) -> None:
    """A non-finite twist is a bug upstream: refused, never turned into a motion."""
    for i, value in zip(where, bad, strict=False):
        twist[i] = value
    with pytest.raises(InputError, match=r"^twist: "):
        ik.joint_velocity(0.5 * (ik.lower + ik.upper), twist, 0.05)

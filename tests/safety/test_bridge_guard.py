"""The bridge guard holds its limits whatever it is sent.

Unit tests per limit use a linear "arm" (the endpoint moves 0.5 m per rad of joints 0..2,
along x, y, z), so every number is exact; the properties run random command, stop, resume
and wait sequences through the Sawyer's real forward kinematics.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import assume, event, given, settings
from hypothesis import strategies as st

from legws_daemon.arms import arm
from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.formats.bridge_messages import STOP_ROLES
from legws_daemon.formats.profile import COMMAND_BURST, BridgeLimitsSpec, WorkspaceBox
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.world import World
from legws_daemon.safety.bridge_guard import LIMITS, BridgeGuard, box_distance, grown
from legws_daemon.scene.catalog import load_scene

LIMITS_SPEC = BridgeLimitsSpec()  # 0.8 rad/s, 0.2 m/s, 0.02 m, 0.2 s, 60 Hz
BOX = WorkspaceBox()  # x [0.2, 0.95], y [-0.55, 0.55], z [0, 0.6]
CENTER = np.array([0.575, 0.0, 0.3])
GAIN = 0.5  # m per rad, the linear arm
PERIOD = 0.005  # a 200 Hz bridge's integration step
JOINT_LOWER, JOINT_UPPER = arm("sawyer").lower, arm("sawyer").upper
SPEC = np.asarray(arm("sawyer").speed_limits)


def linear_arm(q: FloatArray) -> FloatArray:
    """The endpoint of the linear arm: the box centre at q = 0, 0.5 m per rad along x, y, z."""
    return np.asarray(CENTER + GAIN * np.asarray(q)[:3], dtype=np.float64)


def guard(
    limits: BridgeLimitsSpec = LIMITS_SPEC, fk: Callable[[FloatArray], FloatArray] = linear_arm
) -> BridgeGuard:
    return BridgeGuard(limits, BOX, fk)


def joints(*values: float) -> list[float]:
    return [*values, *[0.0] * (7 - len(values))]


# --- joint speed ------------------------------------------------------------------------
def test_a_fast_command_is_scaled_down_uniformly_to_the_cap() -> None:
    g = guard()
    dq = np.array([0.0, 0.0, 0.0, 1.74, -1.0, 0.5, 0.2])  # j3 over 0.8 by 2.175 times
    assert g.receive(dq, 0.1, 0.0) == "accepted"
    assert g.live is not None
    np.testing.assert_allclose(g.live.dq, dq * 0.8 / 1.74, rtol=1e-15)
    assert g.live.dq[3] == pytest.approx(0.8, rel=1e-15)
    assert g.take_limited() == ("joint_speed",)
    assert g.take_limited() == ()  # reported once
    assert g.counts["joint_speed"] == 1
    step = g.step(np.zeros(7), 0.0, PERIOD)
    np.testing.assert_array_equal(step.velocity, g.live.dq)  # no other limit applies
    assert step.duration == PERIOD


def test_slow_commands_pass_unchanged() -> None:
    g = guard()
    dq = np.array(joints(0.1, -0.2, 0.05, 0.8, -0.8, 0.3, 0.0))
    g.receive(dq, 0.1, 0.0)
    assert g.live is not None
    np.testing.assert_array_equal(g.live.dq, dq)
    assert g.take_limited() == ()


def test_each_joint_is_capped_at_its_specification_too() -> None:
    g = guard(BridgeLimitsSpec(joint_speed_cap=4.0))
    np.testing.assert_array_equal(g.joint_speed_cap, np.minimum(4.0, SPEC))
    g.receive(joints(0.0, 1.328), 0.1, 0.0)  # right_j1 at its 1.328 rad/s: not over
    assert g.take_limited() == ()
    g.receive(joints(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 4.0), 0.1, 0.1)  # right_j6 at the cap
    assert g.take_limited() == ()
    g.receive(joints(0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 4.5), 0.1, 0.2)  # right_j6 over it
    assert g.take_limited() == ("joint_speed",)
    assert g.live is not None
    np.testing.assert_allclose(g.live.dq, np.array(joints(0.0, 1.0, 0, 0, 0, 0, 4.5)) * 4.0 / 4.5)


# --- ttl ----------------------------------------------------------------------------------
def test_a_command_moves_at_most_max_ttl() -> None:
    g = guard()
    g.receive(joints(0.1), 1.0, 10.0)
    assert g.take_limited() == ("ttl",)
    assert g.live is not None
    assert g.live.expires == pytest.approx(10.2)
    step = g.step(np.zeros(7), 10.0, 11.0)  # one long step past the expiry
    assert step.duration == pytest.approx(0.2)
    assert g.live is None  # the deadman
    assert g.step(np.zeros(7), 11.0, 12.0).duration == 0.0


def test_a_short_ttl_is_kept_and_not_reported() -> None:
    g = guard()
    g.receive(joints(0.1), 0.1, 0.0)
    assert g.take_limited() == ()
    total = sum(g.step(np.zeros(7), t, t + PERIOD).duration for t in np.arange(0.0, 0.3, PERIOD))
    assert total == pytest.approx(0.1)


# --- rate -------------------------------------------------------------------------------
def test_a_burst_beyond_the_bucket_is_refused_and_stops_the_arm() -> None:
    g = guard()
    for _ in range(COMMAND_BURST):
        assert g.receive(joints(0.1), 0.2, 0.0) == "accepted"
    assert g.take_limited() == ()
    assert g.receive(joints(0.1), 0.2, 0.0) == "refused"
    assert g.live is None  # the arm stops
    assert g.take_limited() == ("rate",)
    assert g.step(np.zeros(7), 0.0, PERIOD).duration == 0.0
    # one token comes back per 1/60 s
    assert g.receive(joints(0.1), 0.2, 0.5 / 60) == "refused"
    assert g.receive(joints(0.1), 0.2, 1.0 / 60) == "accepted"
    assert g.counts["rate"] == 2


def test_the_rate_itself_is_always_accepted() -> None:
    g = guard()
    verdicts = {g.receive(joints(0.1), 0.2, k / 60.0 + 1e-9 * k) for k in range(600)}
    assert verdicts == {"accepted"}
    fast = guard()  # 100 Hz for 1 s: 60 + 5 accepted
    accepted = sum(fast.receive(joints(0.1), 0.2, k / 100.0) == "accepted" for k in range(100))
    assert accepted == pytest.approx(60 * 0.99 + COMMAND_BURST, abs=1)


# --- EE speed ---------------------------------------------------------------------------
def test_a_step_faster_than_the_ee_cap_is_scaled_to_it() -> None:
    g = guard()
    g.receive(joints(0.8), 0.2, 0.0)  # 0.4 m/s along x
    step = g.step(np.zeros(7), 0.0, PERIOD)
    assert step.velocity[0] == pytest.approx(0.4, rel=1e-8)
    np.testing.assert_array_equal(step.velocity[1:], 0.0)
    speed = np.linalg.norm(linear_arm(step.displacement) - CENTER) / step.duration
    assert speed <= LIMITS_SPEC.ee_speed_cap
    assert g.take_limited() == ("ee_speed",)
    assert g.live is not None  # scaled, not stopped


def test_the_ee_cap_holds_on_a_curved_path() -> None:
    """The Sawyer's own kinematics: its base joint at 0.8 rad/s swings the endpoint at
    ~0.44 m/s; every step is held to 0.2 m/s, measured as the step's chord."""
    world, q0 = sawyer()
    g = guard(fk=fk_of(world))
    g.receive(joints(0.8), 0.2, 0.0)
    q = q0.copy()
    for t in np.arange(0.0, 0.2, PERIOD):
        step = g.step(q, t, t + PERIOD)
        nxt = q + step.displacement
        chord = np.linalg.norm(fk_of(world)(nxt) - fk_of(world)(q))
        assert chord <= LIMITS_SPEC.ee_speed_cap * PERIOD * (1 + 1e-12)
        assert chord >= LIMITS_SPEC.ee_speed_cap * PERIOD * 0.999  # scaled to, not below
        q = nxt
    assert g.counts["ee_speed"] == 40


# --- workspace ----------------------------------------------------------------------------
def q_at(p: list[float]) -> FloatArray:
    """The linear arm's joints with the endpoint at ``p``."""
    return np.array(joints(*((np.array(p) - CENTER) / GAIN)))


def test_a_step_out_of_the_box_is_not_taken_and_stops_the_arm() -> None:
    g = guard()
    q = q_at([0.95 + 0.0199, 0.0, 0.3])  # inside the margin, 0.1 mm from its face
    g.receive(joints(0.3), 0.2, 0.0)  # +x at 0.15 m/s: 0.75 mm per step
    assert g.step(q, 0.0, PERIOD).duration == 0.0
    assert g.live is None
    assert g.take_limited() == ("workspace",)
    g.receive(joints(-0.3), 0.2, 0.1)  # back in: allowed
    assert g.step(q, 0.1, 0.1 + PERIOD).duration == pytest.approx(PERIOD)


def test_outside_only_steps_that_do_not_go_farther_are_allowed() -> None:
    g = guard()
    q = q_at([1.2, 0.0, 0.3])  # 0.23 m beyond the margin's face
    for t, (dq, allowed) in enumerate(
        [
            (joints(-0.2), True),  # back toward the box
            (joints(0.0, 0.2), True),  # along the face: no farther
            (joints(0.2), False),  # farther out
            (joints(-0.01, 0.0, 0.0, 0.3), True),  # inward, and a joint that does not move it
        ]
    ):
        g.receive(dq, 0.2, t)
        step = g.step(q, t, t + PERIOD)
        assert (step.duration > 0.0) is allowed, dq
        assert (g.live is not None) is allowed
    assert g.counts["workspace"] == 1


def test_box_distance_and_growth() -> None:
    box = grown(BOX, 0.02)
    np.testing.assert_allclose(box.lower, [0.18, -0.57, -0.02])
    np.testing.assert_allclose(box.upper, [0.97, 0.57, 0.62])
    assert box_distance(box, CENTER) == 0.0
    assert box_distance(box, np.array([1.0, 0.6, 0.3])) == pytest.approx(math.hypot(0.03, 0.03))


# --- joint position limits ------------------------------------------------------------------
def test_a_joint_at_its_limit_is_not_driven_further() -> None:
    g = guard()
    q = np.zeros(7)
    q[5] = JOINT_UPPER[5]
    q[6] = JOINT_LOWER[6] + 1e-4
    g.receive([0.0, 0.0, 0.0, 0.0, 0.0, 0.5, -0.5], 0.2, 0.0)
    step = g.step(q, 0.0, PERIOD)
    assert step.velocity[5] == 0.0
    assert (q + step.displacement)[6] == pytest.approx(JOINT_LOWER[6])


# --- the stop latch -----------------------------------------------------------------------
def test_a_stop_latches_until_a_resume() -> None:
    g = guard()
    g.receive(joints(0.1), 0.2, 0.0)
    g.stop("observer")
    assert g.live is None
    assert g.stopped_by == "observer"
    g.stop("operator")  # the first role is kept
    assert g.stopped_by == "observer"
    assert g.receive(joints(0.1), 0.2, 0.05) == "ignored"
    assert g.step(np.zeros(7), 0.05, 0.1).duration == 0.0
    assert g.resume() is True
    assert g.stopped_by is None
    assert g.step(np.zeros(7), 0.1, 0.15).duration == 0.0  # no command comes back
    assert g.receive(joints(0.1), 0.2, 0.2) == "accepted"
    assert g.step(np.zeros(7), 0.2, 0.25).duration > 0.0
    assert g.resume() is False


def test_clear_and_bad_arguments() -> None:
    g = guard()
    g.receive(joints(0.1), 0.2, 0.0)
    g.clear()
    assert g.live is None
    assert g.receive(joints(math.nan), 0.2, 0.1) == "rejected"
    assert g.receive(joints(0.1), math.inf, 0.2) == "rejected"
    assert g.live is None
    g.receive(joints(0.1), 0.2, 0.3)
    assert g.step([math.nan] * 7, 0.3, 0.31).duration == 0.0
    assert g.live is None
    with pytest.raises(InputError, match="burst"):
        BridgeGuard(LIMITS_SPEC, BOX, linear_arm, burst=0)
    with pytest.raises(InputError, match="7 values each"):
        BridgeGuard(LIMITS_SPEC, BOX, linear_arm, lower=[0.0] * 6)


# --- properties on the Sawyer's kinematics --------------------------------------------------
_SAWYER: list[tuple[World, FloatArray]] = []


def sawyer() -> tuple[World, FloatArray]:
    """The Sawyer model and its home configuration for the desk (built once)."""
    if not _SAWYER:
        scene = load_scene("desk")
        world = World(scene, visual=False)
        q0 = home_configuration(world, scene.home.position, scene.home.rotation).q
        _SAWYER.append((world, np.asarray(q0, dtype=np.float64)))
    return _SAWYER[0]


def fk_of(world: World) -> Callable[[FloatArray], FloatArray]:
    def ee_position(q: FloatArray) -> FloatArray:
        world.set_q(q)
        return world.ee_position()

    return ee_position


#: One event: maybe a stop or a resume (rarer: a latched stop moves nothing), maybe a
#: command (any the contract lets in: up to the specification speeds, any ttl), then a wait.
events = st.lists(
    st.tuples(
        st.sampled_from([None] * 8 + [*STOP_ROLES, "resume"]),
        st.none() | st.tuples(st.tuples(*[st.floats(-s, s) for s in SPEC]), st.floats(1e-3, 1.0)),
        st.floats(0.0, 0.08),
    ),
    min_size=1,
    max_size=30,
)
offsets = st.lists(st.floats(-1.5, 1.5), min_size=7, max_size=7)
Event = tuple[str | None, tuple[tuple[float, ...], float] | None, float]


@settings(max_examples=300, deadline=None)
@given(offsets, events, st.booleans())
def test_whatever_it_is_sent_the_limits_hold(
    offset: list[float], sequence: list[Event], from_home: bool
) -> None:
    """Any sequence of commands (as fast as the contract allows, any ttl), stops, resumes
    and waits, from home or from anywhere: per integration step, no joint faster than its
    cap, the endpoint no faster than its cap, inside the box (+ margin) when it started
    inside, never farther from it when outside; no motion after a command's (capped) ttl,
    none while stopped; never more commands admitted than the rate and the burst."""
    world, home = sawyer()
    fk = fk_of(world)
    q = home + (0.1 * np.array(offset) if from_home else np.array(offset))
    q = np.clip(q, JOINT_LOWER, JOINT_UPPER)
    g = guard(fk=fk)
    box = g.box
    if from_home:
        assume(box.contains(fk(q), tol=0.0))
    t = 0.0
    deadline = -math.inf  # the live command moves the arm until then at most
    stopped = False
    admitted: list[float] = []
    for control, command, wait in sequence:
        if control == "resume":
            g.resume()
            stopped = False
        elif control is not None:
            g.stop(control)
            stopped, deadline = True, -math.inf
        if command is not None:
            dq, ttl = command
            verdict = g.receive(dq, ttl, t)
            if verdict != "refused":
                admitted.append(t)
            if verdict == "accepted":
                assert not stopped
                deadline = t + min(ttl, LIMITS_SPEC.max_ttl)
            else:  # refused (the arm stops) or ignored (only while stopped)
                assert verdict == "refused" or stopped
                deadline = -math.inf
        end = t + wait
        while t < end:
            t1 = min(end, t + PERIOD)
            step = g.step(q, t, t1)
            nxt = q + step.displacement
            moved = np.abs(nxt - q)
            if np.any(moved > 0.0):
                event("moved")
                assert not stopped
                assert t < deadline
                assert step.duration <= min(t1, deadline) - t + 1e-12
            ulp = 2 * np.spacing(np.abs(q) + 1.0)  # adding a step to q rounds to this
            assert np.all(moved <= g.joint_speed_cap * (t1 - t) * (1 + 1e-12) + ulp)
            p0, p1 = fk(q), fk(nxt)
            chord = float(np.linalg.norm(p1 - p0))
            assert chord <= LIMITS_SPEC.ee_speed_cap * (t1 - t) * (1 + 1e-9) + 1e-15
            if box.contains(p0, tol=0.0):
                assert box.contains(p1, tol=0.0)
            else:
                assert box_distance(box, p1) <= box_distance(box, p0)
            q, t = nxt, t1
    rate, burst = LIMITS_SPEC.command_rate_hz, COMMAND_BURST
    for i, ti in enumerate(admitted):  # in any window: the burst plus the rate
        for j in range(i, len(admitted)):
            assert j - i + 1 <= burst + rate * (admitted[j] - ti) + 1e-9
    assert set(g.take_limited()) <= set(LIMITS)
    for limit, n in g.counts.items():
        if n:
            event(f"enforced {limit}")  # what the examples exercised (--hypothesis-show-statistics)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0.0, 0.05), min_size=1, max_size=200))
def test_the_bucket_admits_at_most_the_burst_plus_the_rate(gaps: list[float]) -> None:
    g = guard()
    times = np.cumsum(gaps)
    admitted = [float(t) for t in times if g.admit(float(t))]
    for i, ti in enumerate(admitted):
        for j in range(i, len(admitted)):
            assert j - i + 1 <= COMMAND_BURST + 60.0 * (admitted[j] - ti) + 1e-9
    refused = len(times) - len(admitted)
    assert g.counts["rate"] == refused


# --- the chain a bridge without MuJoCo computes its endpoint with ---------------------------
def test_the_shipped_chain_is_the_models_kinematics() -> None:
    """bridge/chains/sawyer.json is the model's (regenerate: ``python -c "from
    legws_daemon.robot.chain_file import write_chain; write_chain()"``), and its forward
    kinematics (standard library) is MuJoCo's to 1e-12 m over the joint ranges."""
    import json

    from legws_daemon.robot.chain_file import CHAIN_DIR, chain_links
    from legws_daemon.safety.limits import Chain

    shipped = json.loads((CHAIN_DIR / "sawyer.json").read_text(encoding="utf-8"))
    model = json.loads(json.dumps(chain_links()))
    for ours, theirs in zip(shipped["links"], model, strict=True):
        assert ours.keys() == theirs.keys()
        for key, value in ours.items():
            expected = theirs[key] if key == "joint" else pytest.approx(theirs[key], abs=1e-15)
            assert value == expected
    chain = Chain.from_json(json.dumps(shipped))
    world, _ = sawyer()
    rng = np.random.default_rng(7)
    for _ in range(100):
        q = rng.uniform(JOINT_LOWER, JOINT_UPPER)
        world.set_q(q)
        np.testing.assert_allclose(chain.position(q.tolist()), world.ee_position(), atol=1e-12)

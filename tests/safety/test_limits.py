"""The one limit module every bridge runs (``legws_daemon/safety/limits.py``).

Unit tests on a linear "arm" (the endpoint moves 0.5 m per rad of joints 0..2 along x, y,
z: every number exact) and on the Sawyer's chain; properties (hypothesis) over any
sequence of commands, stops, resumes and waits on a clock the test holds; and the module
itself under Python 3.8 (ROS Noetic's), when that interpreter is installed.
"""

from __future__ import annotations

import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from legws_daemon.arms import arm, arm_names
from legws_daemon.formats.profile import COMMAND_BURST, BridgeLimitsSpec, WorkspaceBox
from legws_daemon.safety import limits as L  # noqa: N812

SAWYER = arm("sawyer")
CENTER = (0.575, 0.0, 0.3)
GAIN = 0.5
PERIOD = 0.005
PY38 = [
    p
    for p in (str(Path.home() / ".pyenv/versions/3.8.18/bin/python"), "/usr/bin/python3.8")
    if Path(p).exists()
]


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def linear(q: object) -> tuple[float, float, float]:
    v = list(q)  # type: ignore[call-overload]
    return (CENTER[0] + GAIN * v[0], CENTER[1] + GAIN * v[1], CENTER[2] + GAIN * v[2])


def guard(clock: Clock | None = None, **kw: object) -> L.Guard:
    return L.Guard.for_arm(SAWYER, clock=clock or Clock(), ee_position=linear, period=PERIOD, **kw)  # type: ignore[arg-type]


def joints(*values: float, n: int = 7) -> list[float]:
    return [*values, *[0.0] * (n - len(values))]


def test_defaults_are_the_profiles() -> None:
    spec, box = BridgeLimitsSpec(), WorkspaceBox()
    lim = L.BridgeLimits()
    for name in BridgeLimitsSpec.model_fields:
        assert getattr(lim, name) == getattr(spec, name), name
    assert lim.workspace == (box.x, box.y, box.z)
    assert lim.burst == COMMAND_BURST
    with pytest.raises(ValueError, match="max_ttl"):
        L.BridgeLimits(max_ttl=2.0)
    with pytest.raises(ValueError, match="workspace x"):
        L.BridgeLimits(workspace=((1.0, 0.0), (0.0, 1.0), (0.0, 1.0)))


def test_the_joint_tables_come_from_the_arm() -> None:
    for name in arm_names():
        spec = arm(name)
        g = L.Guard.for_arm(spec, ee_position=linear)
        assert g.dof == spec.dof
        assert g.joint_caps == tuple(min(0.8, s) for s in spec.speed_limits)
        assert g.command(joints(0.1, n=spec.dof), 0.1) == "accepted"
        assert g.command(joints(0.1, n=spec.dof + 1), 0.1) == "rejected"


def test_each_rule_and_its_reason() -> None:
    clock = Clock()
    g = guard(clock)
    assert g.step(joints()).reason == "no command"
    # joint speed: scaled uniformly, direction kept
    assert g.command(joints(0.0, 0.0, 0.0, 1.6, -0.8), 1.0) == "accepted"
    assert g.live is not None
    assert g.live.dq[3:5] == pytest.approx((0.8, -0.4))
    assert g.take_limited() == ("joint_speed", "ttl")
    # the command's life: max_ttl on the injected clock
    clock.now = 0.2
    assert g.step(joints()).reason == "expired"
    assert g.live is None
    # the endpoint speed: 0.8 rad/s on joint 0 is 0.4 m/s, scaled to 0.2
    g.command(joints(0.8), 0.2)
    s = g.step(joints())
    assert s.velocity[0] == pytest.approx(0.4, rel=1e-6)
    assert s.duration == pytest.approx(PERIOD)
    assert "ee_speed" in g.take_limited()
    # the workspace: 0.1 mm inside the margin's face, pushed out: zero, cleared
    q = joints((0.97 - 1e-4 - CENTER[0]) / GAIN)
    g.command(joints(0.3), 0.2)
    s = g.step(q)
    assert (s.velocity, s.reason) == ((0.0,) * 7, "workspace") and g.live is None
    g.command(joints(-0.3), 0.2)  # back in
    assert g.step(q).moving
    # the joint position limit: reached, not passed
    q = joints()
    q[5] = SAWYER.upper[5]
    g.command(joints(0.0, 0.0, 0.0, 0.0, 0.0, 0.5), 0.2)
    assert g.step(q).reason == "joint limit"
    # invalid: NaN, inf, wrong length, bad ttl, an invalid joint state
    clock.now = 5.0
    for dq, ttl in ((joints(math.nan), 0.1), (joints(math.inf), 0.1), ([0.1] * 6, 0.1),
                    (joints(0.1), 0.0), (joints(0.1), math.nan), (joints(0.1), True)):  # fmt: skip
        g.command(joints(0.1), 0.2)
        assert g.command(dq, ttl) == "rejected" and g.live is None
    clock.now = 10.0  # the bucket full again
    assert g.command(joints(0.1), 0.2) == "accepted"
    assert g.step([math.nan] * 7).reason == "invalid joint state"


def test_box_distance() -> None:
    lower, upper = (0.18, -0.57, -0.02), (0.97, 0.57, 0.62)
    assert L.box_distance(CENTER, lower, upper) == 0.0
    assert L.box_distance((1.0, 0.6, 0.3), lower, upper) == pytest.approx(math.hypot(0.03, 0.03))
    assert L.box_distance((0.1, 0.0, 0.3), lower, upper) == pytest.approx(0.08)


def test_from_outside_only_steps_no_farther_are_taken() -> None:
    g = guard()
    q = joints((1.2 - CENTER[0]) / GAIN)  # 0.23 m beyond the margin's face
    for dq, allowed in ((joints(-0.2), True), (joints(0.0, 0.2), True), (joints(0.2), False)):
        g.command(dq, 0.2, 0.0)
        assert g.step(q, 0.0, PERIOD).moving is allowed, dq


def test_the_rate_is_a_token_bucket_on_the_clock() -> None:
    clock = Clock()
    g = guard(clock)
    for _ in range(COMMAND_BURST):
        assert g.command(joints(0.1), 0.2) == "accepted"
    assert g.command(joints(0.1), 0.2) == "refused"
    assert g.live is None and g.take_limited() == ("rate",)
    clock.now = 0.5 / 60
    assert g.command(joints(0.1), 0.2) == "refused"
    clock.now = 1.0 / 60
    assert g.command(joints(0.1), 0.2) == "accepted"


def test_a_stop_latches_until_an_explicit_resume() -> None:
    g = guard()
    g.command(joints(0.1), 0.2)
    g.stop("observer")
    g.stop("operator")
    assert g.stopped_by == "observer" and g.latched == ("observer", "operator")
    assert g.command(joints(0.1), 0.2) == "ignored"
    assert g.step(joints()).reason == "stopped"
    assert g.resume("safety") is False  # another role's resume: still latched
    assert g.resume("observer") is False  # the operator's stop holds still
    assert g.stopped_by == "operator"
    assert g.resume("operator") is True
    assert g.step(joints()).reason == "no command"  # no command comes back
    g.stop("operator")
    assert g.resume() is True  # the daemon's resume (the contract's bridge/resume)
    assert g.command(joints(0.1), 0.2) == "accepted"


def test_the_measured_mode_bounds_a_new_direction() -> None:
    """Without forward kinematics (weaker): a new direction moves the endpoint at most to
    the box's face (REACH x the joint speeds), a parallel one is predicted from the
    measured endpoint velocity; no measurement: no motion."""
    g = L.Guard.for_arm(SAWYER, clock=Clock(), period=0.01)
    g.command(joints(0.8), 0.2)
    assert g.step(joints()).reason == "no endpoint"
    face = (0.969, 0.0, 0.3)  # 1 mm inside the margin's face
    s = g.step(joints(), measured=(face, (0.0, 0.0, 0.0)))
    assert L.REACH * sum(abs(v) for v in s.velocity) * 0.01 == pytest.approx(0.001)
    s = g.step(joints(), measured=(face, (0.6, 0.0, 0.0)))  # parallel, measured too fast
    assert s.reason == "workspace"


def test_the_chain_is_the_models_kinematics() -> None:
    """A chain of fixed transforms and revolute joints: a two-link planar arm."""
    chain = L.Chain(
        [
            {"pos": [0, 0, 0], "quat": [1, 0, 0, 0], "axis": [0, 0, 1]},
            {"pos": [1, 0, 0], "quat": [1, 0, 0, 0], "axis": [0, 0, 1]},
            {"pos": [0.5, 0, 0], "quat": [1, 0, 0, 0]},
        ]
    )
    assert chain.dof == 2
    a, b = 0.3, -0.7
    x, y, _ = chain.position([a, b])
    assert x == pytest.approx(math.cos(a) + 0.5 * math.cos(a + b))
    assert y == pytest.approx(math.sin(a) + 0.5 * math.sin(a + b))
    with pytest.raises(ValueError, match="joint angles"):
        chain.position([0.0])


# --- properties ------------------------------------------------------------------------
SPEC = SAWYER.speed_limits
_bad = st.sampled_from([math.nan, math.inf, -math.inf])
events = st.lists(
    st.tuples(
        st.sampled_from(
            [None] * 6
            + ["operator", "observer", "safety", "resume-same", "resume-other", "resume-daemon"]
        ),
        st.none()
        | st.tuples(st.tuples(*[st.floats(-2 * s, 2 * s) for s in SPEC]), st.floats(1e-3, 1.0))
        | st.tuples(st.lists(st.floats(-1, 1) | _bad, min_size=6, max_size=8), st.floats(0.1, 1))
        | st.tuples(st.tuples(*[st.floats(-1, 1)] * 6, _bad), st.floats(0.1, 1))
        | st.tuples(st.just((0.1,) * 7), _bad | st.just(0.0) | st.just(-1.0)),
        st.floats(0.0, 0.08),
    ),
    min_size=1,
    max_size=30,
)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=7, max_size=7), events)
def test_whatever_it_is_sent_no_cap_is_exceeded(start: list[float], sequence: list) -> None:  # type: ignore[type-arg]
    """Never over a joint cap or the endpoint cap, never out of the box from inside, never
    farther from outside; zero with a reason when invalid, expired or stopped; a stop
    holds until a resume of its own role or the daemon's."""
    clock = Clock()
    g = guard(clock)
    q = np.array(start) * 0.3
    caps = np.array(g.joint_caps)
    lo, hi = np.array(g.box_lower), np.array(g.box_upper)
    latched: list[str] = []
    deadline = -math.inf
    for control, command, wait in sequence:
        if control in ("operator", "observer", "safety"):
            g.stop(control)
            latched += [control] if control not in latched else []
            deadline = -math.inf
        elif control == "resume-daemon":
            g.resume()
            latched = []
        elif control == "resume-same" and latched:
            g.resume(latched[-1])
            latched.pop()
        elif control == "resume-other":
            g.resume("bridge")  # latched by nobody here: changes nothing
        assert g.latched == tuple(latched)
        if command is not None:
            dq, ttl = command
            verdict = g.command(dq, ttl)
            valid = len(dq) == 7 and all(map(math.isfinite, dq)) and ttl > 0 and math.isfinite(ttl)
            if not valid:
                assert verdict == "rejected" and g.live is None
                deadline = -math.inf
            elif latched:
                assert verdict in ("ignored", "refused") and g.live is None
            elif verdict == "accepted":
                deadline = clock.now + min(ttl, g.limits.max_ttl)
            else:
                assert verdict == "refused" and g.live is None
                deadline = -math.inf
        end = clock.now + wait
        while clock.now < end:
            t1 = min(end, clock.now + PERIOD)
            step = g.step(list(q), clock.now, t1)
            v = np.array(step.velocity)
            if step.moving:
                assert not latched and clock.now < deadline
                assert step.duration <= min(t1, deadline) - clock.now + 1e-12
                assert step.reason is None
            else:
                assert not np.any(v) or step.duration == 0.0
                if latched:
                    assert step.reason == "stopped"
            assert np.all(np.abs(v) <= caps * (1 + 1e-12))
            nxt = q + v * step.duration
            p0, p1 = np.array(linear(q)), np.array(linear(nxt))
            if step.duration > 0:
                speed = np.linalg.norm(p1 - p0) / step.duration
                assert speed <= g.limits.ee_speed_cap * (1 + 1e-9)
            inside0 = bool(np.all((lo <= p0) & (p0 <= hi)))
            if inside0:
                assert np.all((lo <= p1) & (p1 <= hi))
            q, clock.now = nxt, t1


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0.0, 0.05), min_size=1, max_size=200))
def test_the_bucket_admits_at_most_the_burst_plus_the_rate(gaps: list[float]) -> None:
    clock = Clock()
    g = guard(clock)
    admitted = []
    for gap in gaps:
        clock.now += gap
        if g.admit():
            admitted.append(clock.now)
    for i, ti in enumerate(admitted):
        for j in range(i, len(admitted)):
            assert j - i + 1 <= COMMAND_BURST + 60.0 * (admitted[j] - ti) + 1e-9
    assert g.counts["rate"] == len(gaps) - len(admitted)


@pytest.mark.skipif(not PY38, reason="no Python 3.8 interpreter here")
def test_the_module_runs_under_python_3_8(tmp_path: Path) -> None:
    """ROS Noetic's Python: the module and the arm tables, standard library only."""
    root = Path(__file__).parents[2]
    script = (
        "import sys; sys.path.insert(0, sys.argv[1])\n"
        "from legws_daemon.safety import limits as L  # noqa: N812\n"
        "from legws_daemon.arms import arm\n"
        "t = [0.0]\n"
        "fk = lambda q: (0.5, 0, 0.3)\n"
        "g = L.Guard.for_arm(arm('panda'), clock=lambda: t[0], ee_position=fk)\n"
        "assert g.command([0.1] * 7, 0.1) == 'accepted'\n"
        "assert g.step([0.0] * 7).moving\n"
        "t[0] = 1.0\n"
        "assert g.step([0.0] * 7).reason == 'expired'\n"
        "assert sys.version_info[:2] == (3, 8)\n"
        "print('ok')\n"
    )
    # a copy of only the stdlib modules (the package's __init__ reads importlib.metadata)
    for rel in ("legws_daemon/__init__.py", "legws_daemon/safety/__init__.py",
                "legws_daemon/safety/limits.py"):  # fmt: skip
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(root / rel, tmp_path / rel)
    shutil.copytree(root / "legws_daemon/arms", tmp_path / "legws_daemon/arms")
    out = subprocess.run(
        [PY38[0], "-I", "-c", script, str(tmp_path)], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"
    assert sys.version_info >= (3, 11)

"""Shared pieces of the reliability tests (issue 7): the controller on the real stand-in,
the safety invariants checked after every tick, and the tally of what the fuzzers fed.

The rig is the daemon's control path without zenoh: payloads go through the same calls
the service makes (:meth:`JoystickInbox.offer`, :func:`parse` of a command or an objects
message, the controller's verbs (``operator_command``), :meth:`Controller.observe`) and the loop's
:meth:`Controller.tick`. The adapter is the real :class:`SimAdapter`; only its MuJoCo
world is compiled once per scene name and reused (0.5 s each) when a ``load_*`` command
swaps scenes.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import numpy as np

from legws_daemon.autonomy.controller import Controller
from legws_daemon.autonomy.inputs import TickRecord
from legws_daemon.core.params import Params
from legws_daemon.daemon.inbox import JoystickInbox, Sample
from legws_daemon.errors import LegwsError
from legws_daemon.formats.messages import StatusMessage
from legws_daemon.formats.profile import ProfileSpec, load_profile
from legws_daemon.hardware.sim import SimAdapter
from legws_daemon.robot.kinematics import home_configuration
from legws_daemon.robot.world import World
from legws_daemon.scene.catalog import load_scene
from legws_daemon.scene.scene import Scene

T = TypeVar("T")
PROFILE = Path(__file__).parents[2] / "hw_profiles" / "sim.toml"
#: How far outside the workspace box the measured EE may be, m (float rounding only).
BOX_TOL = 1e-6
#: Relative slack on speed limits (float rounding only).
SPEED_TOL = 1e-9
#: A joystick deflection may exceed norm 1 by this much (messages.py accepts it).
AXES_NORM_SLACK = 1e-6


def fast_profile() -> ProfileSpec:
    """The shipped ``sim`` profile, not paced to the wall clock."""
    p = load_profile(PROFILE)
    return p.model_copy(update={"sim": p.sim.model_copy(update={"realtime": False})})


class CachedWorldSimAdapter(SimAdapter):
    """The real stand-in, whose compiled world is kept per scene name and reused.

    ``connect`` does what :meth:`SimAdapter.connect` does (a world for the scene, the arm
    at the EE home) with a world that another adapter gave back on ``disconnect``, if
    there is one; no two connected adapters share a world.
    """

    _idle: ClassVar[dict[str, list[World]]] = {}

    def _connect(self) -> None:
        idle = self._idle.setdefault(self.scene.name, [])
        world = idle.pop() if idle else World(self.scene)
        home = home_configuration(world, self.scene.home.position, self.scene.home.rotation)
        self.q_home = home.q
        self.world = world

    def _disconnect(self) -> None:
        if self.world is not None:
            self._idle.setdefault(self.scene.name, []).append(self.world)
        super()._disconnect()


@dataclass
class Tally:
    """What one fuzz test fed and how it was answered (printed in the terminal summary)."""

    examples: int = 0
    payloads: int = 0
    outcomes: Counter[str] = field(default_factory=Counter)
    reasons: Counter[str] = field(default_factory=Counter)
    ticks: int = 0
    modes: Counter[str] = field(default_factory=Counter)

    def line(self, name: str) -> str:
        out = ", ".join(f"{k} {v}" for k, v in sorted(self.outcomes.items()))
        top = ", ".join(f"{k} {v}" for k, v in self.reasons.most_common(6))
        modes = ", ".join(f"{k} {v}" for k, v in sorted(self.modes.items()))
        return (
            f"{name}: {self.examples} examples, {self.payloads} payloads ({out})"
            + (f"; {self.ticks} ticks ({modes})" if self.ticks else "")
            + (f"; rejected by field: {top}" if top else "")
        )


#: Test name -> tally; ``tests/conftest.py`` prints them after the run (also under xdist).
TALLIES: dict[str, Tally] = {}


def expect(
    allowed: type[LegwsError], call: Callable[..., T], *args: Any
) -> tuple[T | None, LegwsError | None]:
    """``call(*args)``: its result, or the ``allowed`` error it raised (one line, checked).

    Any other exception propagates and fails the test.
    """
    try:
        return call(*args), None
    except allowed as err:
        error = err
    assert len(str(error).splitlines()) == 1, str(error)
    return None, error


def axes_norm(axes: Any) -> float:
    return math.sqrt(sum(float(a) * float(a) for a in axes))


class Rig:
    """A controller on the stand-in, its joystick inbox, a clock, and the invariants.

    Args:
        scene: the scene to start in (``desk``: three candidate goals).
    """

    def __init__(self, scene: str = "desk") -> None:
        self.profile = fast_profile()
        self.dt = 1.0 / self.profile.control.rate_hz
        self.timeout = self.profile.control.deadman_timeout
        control = self.profile.control
        self.status_every = max(1, round(control.rate_hz / control.status_rate_hz))
        self.events: list[tuple[str, dict[str, Any]]] = []
        self.inbox = JoystickInbox(
            "legws/sawyer_sim/joystick", self.timeout, self.profile.control.lease_grace
        )
        self.now = 1000.0
        self.seq = 0
        self.ticks = 0
        self.modes: Counter[str] = Counter()
        desk = load_scene(scene)
        self.c = Controller(
            self.profile,
            desk,
            desk.default_layout(),
            self.make_adapter,
            Params(v_max=self.profile.control.v_max, dt=self.dt),
            lambda event: self.events.append((event.kind, event.detail())),
        )

    def make_adapter(self, scene: Scene) -> SimAdapter:
        adapter = CachedWorldSimAdapter(self.profile, scene)
        adapter.connect()
        return adapter

    @property
    def adapter(self) -> SimAdapter:
        a = self.c.adapter
        assert isinstance(a, SimAdapter)
        return a

    @property
    def world(self) -> World:
        w = self.adapter.world
        assert w is not None
        return w

    def next_seq(self) -> int:
        self.seq += 1
        return self.seq

    def joystick(self, axes: Any, **buttons: bool) -> bytes:
        """A valid joystick payload with the next ``seq`` of source ``rig``."""
        msg: dict[str, Any] = {"schema": 1, "seq": self.next_seq(), "stamp": self.now,
                               "axes": list(axes), "source": "rig"}  # fmt: skip
        if buttons:
            msg["buttons"] = buttons
        return json.dumps(msg).encode()

    def offer(self, payload: bytes) -> Sample | None:
        """One payload into the inbox, as the zenoh subscriber does; checks the counters and
        that a payload not taken leaves the sample the next tick uses unchanged."""
        box = self.inbox
        before = (box.accepted, box.rejected, box.ignored)
        current = box.latest(self.now)
        sample = box.offer(payload, self.now)
        after = (box.accepted, box.rejected, box.ignored)
        # exactly one counter moved, by one: every payload is accounted for
        assert sorted(b - a for a, b in zip(before, after, strict=True)) == [0, 0, 1]
        if sample is None:
            # nothing new is used: the sample stays, or a goodbye ends it
            assert box.latest(self.now) in (current, None)
        else:
            assert after[0] == before[0] + 1
            m = sample.message
            assert all(math.isfinite(a) and -1.0 <= a <= 1.0 for a in m.axes)
            assert axes_norm(m.axes) <= 1.0 + AXES_NORM_SLACK
        return sample

    def tick(self) -> TickRecord:
        """One control period with the inbox's newest valid sample; checks the envelope."""
        self.now += self.dt
        sample = self.inbox.latest(self.now)
        return self.tick_with(sample)

    def tick_with(self, sample: Sample | None) -> TickRecord:
        """One control period with ``sample`` (``None``: no input); checks the envelope."""
        c = self.c
        mode_before = c.mode
        ramping = c.handback.active  # control just came back: the command slews to the stick's
        sent_before = np.array(c._motion, dtype=np.float64)
        adapter = self.adapter
        before = adapter.read_state()
        q_before = before.q
        # the loop calls this unguarded: nothing may escape
        rec = c.tick(sample.operator if sample is not None else None)
        self.ticks += 1
        self.modes[rec.mode.value] += 1  # str keys: xdist sends the tallies home
        check_envelope(self.adapter, rec.command)
        if self.adapter is adapter:  # (a load swaps adapters only inside a load)
            if rec.joints is None:  # a joint step is checked where it ends (check_envelope)
                check_command(adapter, before.ee_position, rec.command)
            if sample is None:
                # stale or no input: exactly zero, and nothing moved, in every mode
                np.testing.assert_array_equal(rec.command, np.zeros(3))
                np.testing.assert_array_equal(adapter.read_state().q, q_before)
            elif mode_before == "teleop" and rec.mode == "teleop":
                limit = self.profile.control.v_max * (1.0 + AXES_NORM_SLACK + SPEED_TOL)
                speed = float(np.linalg.norm(rec.command))
                if ramping:
                    # the hand-back (docs/daemon.md): the command slews from the robot's last
                    # velocity, which may be faster than the stick's, to the stick's (and the
                    # envelope may cut it further): never faster than that last velocity
                    limit = max(limit, float(np.linalg.norm(sent_before)) * (1.0 + 1e-9))
                assert speed <= limit
        if rec.mode in ("idle", "stopped", "fault"):
            np.testing.assert_array_equal(rec.command, np.zeros(3))
        if rec.tick % self.status_every == 0:
            self.check_status(rec)
        return rec

    def check_status(self, rec: TickRecord) -> StatusMessage:
        """The status message of this tick validates (the loop builds it unguarded, at the
        status rate): the controller-derived fields, as ``DaemonService._status`` fills them."""
        c = self.c
        data: dict[str, Any] = {
            "schema": 1, "robot": self.profile.robot, "seq": rec.tick, "stamp": 0.0,
            "mode": c.mode.value, "stage": c.stage.name, "posterior": c.posterior(),
            "committed": c.committed,
            "certificate": c.stage.current_certificate,
            "adapter": "sim", "fault": c.fault, "phase": rec.phase,
            "deadman": rec.joystick is None, "tick": c.ticks, "rejected": self.inbox.rejected,
            "rejections": self.inbox.counts(), "operator": self.inbox.operator(),
            "slack": c.live_slack(), "decision": c.decisions,
            "targets": {t.name: t.position.tolist() for t in c.stage.targets},
        }  # fmt: skip
        if rec.state is not None:
            data["ee"] = {
                "position": rec.state.ee_position.tolist(),
                "quaternion": rec.state.ee_quaternion.tolist(),
            }
            data["gripper_closed"] = rec.state.gripper_closed
        return StatusMessage.model_validate(data)

    def restart_if_done(self) -> None:
        """The task done (idle): start it again, cheaply (the same scene, no new adapter)."""
        if self.c.mode == "idle":
            self.c.load(self.c.scene, None, None)


def check_command(adapter: SimAdapter, position: Any, sent: Any) -> None:
    """The command itself never heads out of the box: from inside, one period of it ends
    inside; on an axis where the EE is outside, it does not point further out."""
    p = np.asarray(position, dtype=np.float64)
    v = np.asarray(sent, dtype=np.float64)
    box = adapter.box
    if box.contains(p, tol=0.0):
        assert box.contains(p + v * adapter.dt, tol=1e-12), (p, v)
    assert np.all(v[p > box.upper] <= 0.0), (p, v)
    assert np.all(v[p < box.lower] >= 0.0), (p, v)


def check_envelope(adapter: SimAdapter, sent: Any) -> None:
    """What was sent is finite and at most ``v_max``; the EE is in the box; every joint
    is within its limits."""
    v = np.asarray(sent, dtype=np.float64)
    assert v.shape == (3,)
    assert np.all(np.isfinite(v)), v
    assert float(np.linalg.norm(v)) <= adapter.v_max * (1.0 + SPEED_TOL), v
    state = adapter.read_state()
    assert adapter.box.contains(state.ee_position, tol=BOX_TOL), state.ee_position
    world = adapter.world
    assert world is not None
    assert np.all(np.isfinite(state.q))
    assert np.all(state.q >= world.arm.lower), state.q
    assert np.all(state.q <= world.arm.upper), state.q

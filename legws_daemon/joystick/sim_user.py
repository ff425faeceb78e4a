"""``legws joystick sim-user``: the noisy user of method.md §2, in real time, in the loop.

The simulated user reads the daemon's status (``legws/<robot>/status``: EE position, mode,
the current decision's goal positions) and pushes the stick toward its goal with Gaussian
velocity noise: ``u = (p_g - p) / |p_g - p| + eps / v_max``, ``eps ~ N(0, sigma^2 I)``,
clipped to ``|u| <= 1``. Once the daemon commits it lets go of the stick (zero deflection,
still publishing: the dead-man switch stays held) and watches the robot act; if it reaches
its goal before the daemon commits it presses *confirm*. In a task graph it picks a goal at
each decision: the first of its wanted goals on offer, or one at random (seeded). Without
a fresh status it publishes nothing — it cannot steer blind, and the daemon's deadman then
holds the robot.

With an ``operator`` (method.md §10: speed, AR(1) noise, aiming bias, quantised steering)
it steers like that model instead: :class:`~legws_daemon.core.user_model.OperatorStick` of
a :class:`~legws_daemon.core.user_model.SimulatedUser` with the robot's clip, fed the time
that really passed between two deflections, so that its noise shows the model's ``rho`` at
the daemon's ticks whatever the publishing rate; the noise starts afresh at each new reach.
In the daemon's ``calibrate`` mode (``legws operator calibrate``) it steers toward the one
target on offer (``targets: {"calibration": [x, y, z]}``) and never confirms.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from legws_daemon.core.geometry import FloatArray
from legws_daemon.core.operator import OperatorModel
from legws_daemon.core.params import Params
from legws_daemon.core.user_model import (
    OperatorStick,
    SimulatedUser,
    clip_unit,
    deflection,
    noise,
)
from legws_daemon.errors import InputError
from legws_daemon.formats.messages import Buttons, StatusMessage
from legws_daemon.joystick.publisher import Sample

#: Within this distance of the goal position the user stops pushing and confirms, metres.
ARRIVED = 0.01
#: The daemon's mode while it calibrates an operator, and the name of its one target.
CALIBRATE = "calibrate"
CALIBRATION_TARGET = "calibration"


@dataclass(frozen=True, slots=True)
class UserView:
    """What the user sees of the robot: the daemon's status, or the controller itself when
    both run in one process (``legws eval``, the in-process demo).

    Attributes:
        mode: the controller's mode; decision: the decision's number in the run.
        stage: the stage (``a|b`` while the user chooses between stages).
        ee_position: where the EE is, m.
        targets: goal -> position of the current decision, m.
    """

    mode: str
    decision: int
    stage: str
    ee_position: FloatArray
    targets: Mapping[str, FloatArray]

    @classmethod
    def from_status(cls, status: StatusMessage) -> UserView | None:
        """The view a status gives, or ``None`` when it has no EE pose."""
        if status.ee is None:
            return None
        targets = {g: np.array(p) for g, p in status.targets.items()}
        return cls(
            status.mode, status.decision, status.stage or "", np.array(status.ee.position),
            targets,
        )  # fmt: skip


def _not_offered(view: UserView, wants: Sequence[str], used: set[str]) -> str:
    """Why the user cannot go on: no goal it was given is a target of this decision."""
    left = [g for g in wants if g not in used]
    targets = ", ".join(sorted(view.targets))
    where = f"decision {view.decision} (stage {view.stage})"
    if not left:
        return (
            f"--goal: every goal given was gone for ({', '.join(wants)}); {where} has the "
            f"targets {targets}: give one --goal per decision"
        )
    return f"--goal: {', '.join(left)} is not a target of {where}; its targets: {targets}"


@dataclass(frozen=True, slots=True)
class UserAction:
    """What the user does this tick: a deflection (3,) and the buttons (with the rotation
    axes and the gripper button of a hand that finishes a pick itself: ``None``, untouched)."""

    axes: FloatArray
    confirm: bool = False
    cancel: bool = False
    rotation: FloatArray | None = None
    gripper: bool | None = None


def _hands_off() -> UserAction:
    return UserAction(np.zeros(3))


@dataclass
class SimUser:
    """The user model (:mod:`legws_daemon.core.user_model`) with a mind of its own.

    Args:
        wants: goals in order of preference; at each decision the first one on offer is
            chosen (and, once chosen, not chosen again). Empty: choose at random.
        sigma: velocity noise, m/s per axis.
        v_max: EE speed at full deflection, m/s.
        rng: noise (and random choice) source.
        cancel_after: press the cancel button this many seconds into assistance, once;
            ``None`` never.
        operator: steer like this operator model (method.md §10) instead of section 2's
            user (``sigma`` is then the model's); ``None``: section 2's user, as before.
        dt: the daemon's control period, s (the period of the operator's ``rho``).
    """

    wants: Sequence[str]
    sigma: float
    v_max: float
    rng: np.random.Generator
    cancel_after: float | None = None
    cancelled: bool = False
    chosen: list[tuple[str, str]] = field(default_factory=list)  # (decision, goal)
    _decision: tuple[int, str, tuple[str, ...]] | None = None
    _goal: str | None = None
    _assist_since: float | None = None
    operator: OperatorModel | None = field(default=None, kw_only=True)
    dt: float = field(default=Params().dt, kw_only=True)
    _stick: OperatorStick | None = field(default=None, init=False, repr=False)
    _reach: tuple[str, tuple[float, ...]] | None = field(default=None, init=False, repr=False)
    _last: float | None = field(default=None, init=False, repr=False)
    # the deflections sent lately (bounded: a status older than these is stale anyway)
    _sent: deque[tuple[float, FloatArray]] = field(
        default_factory=lambda: deque(maxlen=256), init=False, repr=False
    )

    def __post_init__(self) -> None:
        if self.operator is not None:
            user = SimulatedUser(self.operator, clip=True)
            self._stick = OperatorStick(user, Params(v_max=self.v_max, dt=self.dt), self.rng)

    @property
    def goal(self) -> str | None:
        return self._goal

    def choose(self, view: UserView) -> str | None:
        """The goal the user goes for at ``view``'s decision (``None``: nothing to steer
        for) — in ``teleop``; in other modes nothing is chosen.

        Raises:
            InputError: goals were given and none still wanted is a target of a decision
                with several candidates (the user would wait for ever).
        """
        return self._choose(view) if view.mode == "teleop" else None

    def _choose(self, view: UserView) -> str | None:
        offered = tuple(sorted(view.targets))
        key = (view.decision, view.stage, offered)
        if key != self._decision:
            self._decision = key
            used = {g for _, g in self.chosen}
            pick = [g for g in self.wants if g in offered and g not in used]
            if pick:
                self._goal = pick[0]
            elif len(offered) == 1 or (not self.wants and offered):
                # one candidate needs no choice; without wanted goals, one at random
                self._goal = offered[int(self.rng.integers(len(offered)))]
            elif offered:
                raise InputError(_not_offered(view, self.wants, used))
            else:
                self._goal = None
            if self._goal is not None:
                self.chosen.append((key[1], self._goal))
        return self._goal

    def deflection(
        self, position: FloatArray, target: FloatArray, elapsed: float | None = None
    ) -> FloatArray:
        """The stick toward ``target``: method.md §2, clipped to ``|u| <= 1``; with an
        operator, that model's stick ``elapsed`` seconds after the last deflection (default
        one control period)."""
        if self._stick is not None:
            return self._stick.deflection(position, target, elapsed)
        eps = noise(self.rng, (), self.sigma, self.v_max)
        return clip_unit(deflection(position, target, eps))

    def steer(self, goal: str, target: FloatArray, position: FloatArray, now: float) -> FloatArray:
        """This tick's deflection toward ``goal`` at ``target``: a new reach (another goal
        or target, or steering again after a pause) starts the operator's noise afresh."""
        reach = (goal, tuple(float(v) for v in target))
        if reach != self._reach:
            self._reach, self._last = reach, None
            if self._stick is not None:
                self._stick.reset()
        elapsed = None if self._last is None else now - self._last
        self._last = now
        return self.deflection(position, target, elapsed)

    def act(self, view: UserView, now: float) -> UserAction:
        """What the user does given what it sees at ``now`` (seconds)."""
        if view.mode == CALIBRATE:
            # a calibration: the one target on offer, reached (the daemon shows the next one
            # once the EE is within 2 cm), never confirmed
            self._assist_since = None
            target = view.targets.get(CALIBRATION_TARGET)
            if target is None:
                self._reach = None
                return _hands_off()
            return UserAction(self.steer(CALIBRATION_TARGET, target, view.ee_position, now))
        if view.mode == "teleop":
            self._assist_since = None
            goal = self._choose(view)
            if goal is None:
                self._reach = None
                return _hands_off()  # nothing wanted on offer: hold the dead-man, wait
            target = view.targets[goal]
            to_goal = target - view.ee_position
            if math.sqrt(float(to_goal @ to_goal)) < ARRIVED:
                # at the goal and still no commit: confirm it, as a person would
                return UserAction(np.zeros(3), confirm=True)
            return UserAction(self.steer(goal, target, view.ee_position, now))
        self._reach = None  # the robot acts (or stands): the next steering is a new reach
        if view.mode == "assist" and self.cancel_after is not None and not self.cancelled:
            if self._assist_since is None:
                self._assist_since = now
            if now - self._assist_since >= self.cancel_after:
                self.cancelled = True
                return UserAction(np.zeros(3), cancel=True)
        return _hands_off()

    def sample(
        self, status: StatusMessage | None, now: float, received: float | None = None
    ) -> Sample | None:
        """What the user publishes given the newest status (``None``: nothing to go on).

        ``received``: when that status arrived (the same clock as ``now``). Status comes at
        10 Hz, the stick moves the arm at every tick: while the person steers, the EE is
        taken to be where the status said plus what the deflections sent since then moved
        it (``v_max u`` over each one's time), as a person watching the arm sees it — an
        aim from a position up to 100 ms old would turn with it from tick to tick."""
        view = UserView.from_status(status) if status is not None else None
        if view is None:
            return None
        if received is not None and view.mode in ("teleop", CALIBRATE):
            view = replace(view, ee_position=view.ee_position + self._moved_since(received, now))
        a = self.act(view, now)
        self._sent.append((now, np.asarray(a.axes, dtype=np.float64)))
        x, y, z = (float(v) for v in a.axes)
        # a simulated person holding the enable button throughout (it claims a free lease)
        return (x, y, z), Buttons(cancel=a.cancel, confirm=a.confirm, enable=True)

    def _moved_since(self, received: float, now: float) -> FloatArray:
        """How far the deflections sent since ``received`` moved the EE by ``now``."""
        while len(self._sent) > 1 and self._sent[1][0] <= received:
            self._sent.popleft()  # older than the status: in its EE already
        moved = np.zeros(3)
        if not self._sent:
            return moved
        for (t, u), nxt in zip(self._sent, [*list(self._sent)[1:], (now, None)], strict=True):
            start, end = max(t, received), nxt[0]
            if end > start:  # the robot clips |u| to 1
                moved += self.v_max * (end - start) * u / max(1.0, float(np.linalg.norm(u)))
        return moved

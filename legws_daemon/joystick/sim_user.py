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
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.formats.messages import Buttons, StatusMessage, parse
from legws_daemon.joystick.publisher import Axes, Sample, clip_norm

#: A status older than this is not used to steer, seconds.
STATUS_STALE = 0.5
#: Within this distance of the goal position the user stops pushing and confirms, metres.
ARRIVED = 0.01
ZERO: Axes = (0.0, 0.0, 0.0)


@dataclass
class SimUser:
    """The user model.

    Args:
        wants: goals in order of preference; at each decision the first one on offer is
            chosen (and, once chosen, not chosen again). Empty: choose at random.
        sigma: velocity noise, m/s per axis.
        v_max: EE speed at full deflection, m/s.
        rng: noise (and random choice) source.
        cancel_after: press the cancel button this many seconds into assistance, once;
            ``None`` never.
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

    @property
    def goal(self) -> str | None:
        return self._goal

    def _choose(self, status: StatusMessage) -> str | None:
        offered = tuple(sorted(status.targets))
        key = (status.decision, status.stage or "", offered)
        if key != self._decision:
            self._decision = key
            used = {g for _, g in self.chosen}
            pick = [g for g in self.wants if g in offered and g not in used]
            if pick:
                self._goal = pick[0]
            elif not self.wants and offered:
                self._goal = offered[int(self.rng.integers(len(offered)))]
            else:
                self._goal = None
            if self._goal is not None:
                self.chosen.append((key[1], self._goal))
        return self._goal

    def deflection(self, position: FloatArray, target: FloatArray) -> Axes:
        to_goal = target - position
        dist = math.sqrt(float(to_goal @ to_goal))
        if dist < ARRIVED:
            return ZERO
        u = to_goal / dist + self.rng.standard_normal(3) * (self.sigma / self.v_max)
        return clip_norm(u.tolist())

    def sample(self, status: StatusMessage | None, now: float) -> Sample | None:
        """What the user does given the newest status (``None``: nothing to go on)."""
        if status is None or status.ee is None:
            return None
        if status.mode == "teleop":
            self._assist_since = None
            goal = self._choose(status)
            if goal is None:
                return ZERO, Buttons()  # nothing wanted on offer: hold the dead-man, wait
            position = np.array(status.ee.position)
            target = np.array(status.targets[goal])
            if float(np.linalg.norm(target - position)) < ARRIVED:
                # at the goal and still no commit: confirm it, as a person would
                return ZERO, Buttons(confirm=True)
            return self.deflection(position, target), Buttons()
        if status.mode == "assist" and self.cancel_after is not None and not self.cancelled:
            if self._assist_since is None:
                self._assist_since = now
            if now - self._assist_since >= self.cancel_after:
                self.cancelled = True
                return ZERO, Buttons(cancel=True)
        return ZERO, Buttons()


class StatusWatch:
    """The newest valid status of one robot (fed by a zenoh subscriber callback)."""

    def __init__(self, key: str) -> None:
        self.key = key
        self._lock = threading.Lock()
        self._status: StatusMessage | None = None
        self._received = -math.inf
        self.modes_seen: list[str] = []
        self.done = threading.Event()

    def offer(self, payload: bytes) -> None:
        try:
            status = parse(StatusMessage, payload, self.key)
        except InputError:
            return
        with self._lock:
            self._status, self._received = status, time.monotonic()
            if not self.modes_seen or self.modes_seen[-1] != status.mode:
                self.modes_seen.append(status.mode)
        if status.mode == "idle":
            self.done.set()

    def latest(self, now: float) -> StatusMessage | None:
        with self._lock:
            if now - self._received > STATUS_STALE:
                return None
            return self._status

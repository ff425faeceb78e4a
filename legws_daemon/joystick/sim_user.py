"""``legws joystick sim-user``: the noisy user of method.md §2, in real time, in the loop.

The simulated user reads the daemon's published EE position (``legws/<robot>/status``)
and pushes the stick toward its goal's grasp position with Gaussian velocity noise:
``u = (p_g - p) / |p_g - p| + eps / v_max``, ``eps ~ N(0, sigma^2 I)``, clipped to
``|u| <= 1``. Once the daemon commits it lets go of the stick (zero deflection, still
publishing: the dead-man switch stays held) and watches the robot finish; if it reaches
the object before the daemon commits it presses *confirm*. Without a
fresh status it publishes nothing — it cannot steer blind, and the daemon's deadman
then holds the robot.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.formats.messages import Buttons, StatusMessage, parse
from legws_daemon.joystick.publisher import Axes, Sample, clip_norm

#: A status older than this is not used to steer, seconds.
STATUS_STALE = 0.5
#: Within this distance of the grasp position the user lets go, metres.
ARRIVED = 0.01


@dataclass
class SimUser:
    """The user model: deflection toward ``target`` plus noise.

    Args:
        target: the goal's grasp position (3,).
        sigma: velocity noise, m/s per axis.
        v_max: EE speed at full deflection, m/s.
        rng: noise source.
        cancel_after: press the cancel button this many seconds into assistance (tests
            and demos of the cancel path); ``None`` never.
    """

    target: FloatArray
    sigma: float
    v_max: float
    rng: np.random.Generator
    cancel_after: float | None = None
    _assist_since: float | None = None
    cancelled: bool = False

    def deflection(self, position: FloatArray) -> Axes:
        to_goal = self.target - position
        dist = math.sqrt(float(to_goal @ to_goal))
        if dist < ARRIVED:
            return (0.0, 0.0, 0.0)
        u = to_goal / dist + self.rng.standard_normal(3) * (self.sigma / self.v_max)
        return clip_norm(u.tolist())

    def sample(self, status: StatusMessage | None, now: float) -> Sample | None:
        """What the user does given the newest status (``None``: nothing to go on)."""
        if status is None or status.ee is None:
            return None
        if status.mode == "teleop":
            self._assist_since = None
            position = np.array(status.ee.position)
            if float(np.linalg.norm(self.target - position)) < ARRIVED:
                # at the object and still no commit: confirm it, as a person would
                return (0.0, 0.0, 0.0), Buttons(confirm=True)
            return self.deflection(position), Buttons()
        if status.mode == "assist" and self.cancel_after is not None and not self.cancelled:
            if self._assist_since is None:
                self._assist_since = now
            if now - self._assist_since >= self.cancel_after:
                self.cancelled = True
                return (0.0, 0.0, 0.0), Buttons(cancel=True)
        return (0.0, 0.0, 0.0), Buttons()


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

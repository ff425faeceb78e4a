"""The adapter interface and its registry (name -> class, no if/elif factory).

An adapter connects to one robot, reports its state, and sends EE velocity commands. Every
command passes through the safety envelope (:mod:`legws_daemon.safety.envelope`) inside
:meth:`Adapter.send_velocity`, which returns what was actually sent.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType

import numpy as np

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.safety.envelope import Box, clamp_ee_velocity


@dataclass(frozen=True, slots=True)
class RobotState:
    """What the robot reports: joint positions, EE pose, and when it was measured."""

    q: FloatArray  # (7,) rad
    ee_position: FloatArray  # (3,) m
    ee_quaternion: FloatArray  # (4,) [w, x, y, z]
    stamp: float  # monotonic seconds of the measurement


class Adapter(ABC):
    """A robot reached through a hardware profile."""

    def __init__(self, profile: ProfileSpec) -> None:
        self.profile = profile
        ws = profile.workspace
        self.box = Box(np.array([ws.x[0], ws.y[0], ws.z[0]]), np.array([ws.x[1], ws.y[1], ws.z[1]]))
        self.dt = 1.0 / profile.control.rate_hz
        self.v_max = max(profile.control.v_max, profile.control.assist_speed)

    @abstractmethod
    def connect(self) -> None:
        """Open the connection; raise a :class:`~legws_daemon.errors.LegwsError` on failure."""

    @abstractmethod
    def disconnect(self) -> None:
        """Stop the robot and close the connection (idempotent)."""

    @abstractmethod
    def read_state(self) -> RobotState:
        """The latest measured state."""

    @abstractmethod
    def _command(self, velocity: FloatArray, hold: FloatArray | None) -> None:
        """Apply an already clamped EE velocity for one control period."""

    def send_velocity(self, velocity: object, hold: FloatArray | None = None) -> FloatArray:
        """Clamp ``velocity`` to the safety envelope, send it, return what was sent.

        Args:
            velocity: requested EE linear velocity (3,), m/s; anything invalid sends zero.
            hold: EE orientation (3, 3) to hold, or ``None`` for the current one.
        """
        state = self.read_state()
        sent = clamp_ee_velocity(state.ee_position, velocity, self.dt, self.box, self.v_max)
        self._command(sent, hold)
        return sent

    def stop(self) -> FloatArray:
        """Send zero velocity."""
        return self.send_velocity(np.zeros(3))

    def __enter__(self) -> Adapter:
        self.connect()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.disconnect()


_REGISTRY: dict[str, type[Adapter]] = {}


def register(name: str) -> Callable[[type[Adapter]], type[Adapter]]:
    """Class decorator: make an adapter available under ``name``."""

    def add(cls: type[Adapter]) -> type[Adapter]:
        if name in _REGISTRY:
            raise ValueError(f"adapter '{name}' is registered twice")
        _REGISTRY[name] = cls
        return cls

    return add


def adapter_class(name: str) -> type[Adapter]:
    """The adapter registered under ``name``; unknown names list the known ones."""
    try:
        return _REGISTRY[name]
    except KeyError:
        raise InputError(
            f"unknown adapter '{name}'; known: {', '.join(sorted(_REGISTRY))}", field="adapter"
        ) from None


def known_adapters() -> list[str]:
    return sorted(_REGISTRY)

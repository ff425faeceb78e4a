"""The adapter interface and its registry (name -> class, no if/elif factory).

An adapter connects to one robot, reports its state, and sends EE velocity commands. Every
command passes through the safety envelope (:mod:`legws_daemon.safety.envelope`) inside
:meth:`Adapter.send_velocity`, which returns what was actually sent.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import TracebackType
from typing import TYPE_CHECKING

import numpy as np
import zenoh

from legws_daemon.core.geometry import FloatArray
from legws_daemon.errors import InputError
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.safety.envelope import Box, clamp_ee_velocity
from legws_daemon.scene.scene import ObjectPose, Scene

if TYPE_CHECKING:
    from legws_daemon.robot.world import World


@dataclass(frozen=True, slots=True)
class RobotState:
    """What the robot reports: joint positions, EE pose, and when it was measured."""

    q: FloatArray  # (7,) rad
    ee_position: FloatArray  # (3,) m
    ee_quaternion: FloatArray  # (4,) [w, x, y, z]
    stamp: float  # monotonic seconds of the measurement
    gripper_closed: bool = False


class Adapter(ABC):
    """A robot reached through a hardware profile.

    Every adapter is built the same way, so the daemon picks one from the registry by the
    profile's ``adapter`` name.

    Args:
        profile: the hardware profile (rates, limits, workspace box, adapter settings).
        scene: the scene around the robot (the stand-in builds its world from it; a real
            robot's adapter uses it for the kinematic model's table and objects).
        session: the daemon's open zenoh session (adapters that talk to a robot-side
            bridge need it; the stand-in does not).
    """

    def __init__(
        self, profile: ProfileSpec, scene: Scene, session: zenoh.Session | None = None
    ) -> None:
        self.profile = profile
        self.scene = scene
        self.session = session
        self._kinematics: World | None = None
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

    @abstractmethod
    def grip(self, closed: bool) -> None:
        """Close (``True``) or open the gripper."""

    def object_poses(self) -> dict[str, tuple[FloatArray, FloatArray]]:
        """Measured object poses, name -> (position, quaternion ``[w, x, y, z]``).

        Empty when the adapter cannot see objects (a real robot without a tracker; issue
        6 feeds them from ``legws/<robot>/objects``).
        """
        return {}

    def place_objects(self, layout: Mapping[str, ObjectPose]) -> bool:
        """Put objects at ``layout``; ``False`` when a person has to (a real robot)."""
        return False

    def link_poses(self, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Origins ``(K, 3)`` and rotations ``(K, 3, 3)`` of the arm's links at ``q``
        (from a kinematic model of the robot; for drawing)."""
        if self._kinematics is None:
            from legws_daemon.robot.world import World  # compiled once, ~20 ms

            self._kinematics = World(self.scene, visual=False)
        return self._kinematics.link_poses(q)

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

    def halt(self) -> None:
        """Command zero velocity without reading the state first (the state may be what
        failed); adapters that talk to a robot override it to send zero directly."""
        self._command(np.zeros(3), None)

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

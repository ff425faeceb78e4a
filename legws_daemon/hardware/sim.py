"""The ``sim`` adapter: the MuJoCo Sawyer stand-in, paced to real time or as fast as possible."""

from __future__ import annotations

import time

import numpy as np

from legws_daemon.core.geometry import FloatArray, matrix_to_quat
from legws_daemon.errors import LegwsError
from legws_daemon.formats.profile import ProfileSpec
from legws_daemon.hardware.base import Adapter, RobotState, register
from legws_daemon.scene.scene import Scene
from legws_daemon.sim.kinematics import home_configuration, small_rotation_error, velocity_step
from legws_daemon.sim.world import World

#: Gain holding the EE orientation, 1/s.
ORIENTATION_GAIN = 2.0


@register("sim")
class SimAdapter(Adapter):
    """The stand-in: commands move the arm through its differential kinematics.

    Args:
        profile: the hardware profile (``sim.realtime`` paces commands to the wall clock).
        scene: the scene whose table and objects surround the arm; the arm starts at the
            scene's EE home.
    """

    def __init__(self, profile: ProfileSpec, scene: Scene) -> None:
        super().__init__(profile)
        self.scene = scene
        self.world: World | None = None
        self._next_tick = 0.0

    def connect(self) -> None:
        world = World(self.scene)
        home_configuration(world, self.scene.home.position, self.scene.home.rotation)
        self.world = world
        self._next_tick = time.monotonic()

    def disconnect(self) -> None:
        self.world = None

    def _world(self) -> World:
        if self.world is None:
            raise LegwsError("the sim adapter is not connected")
        return self.world

    def read_state(self) -> RobotState:
        w = self._world()
        return RobotState(w.q, w.ee_position(), matrix_to_quat(w.ee_rotation()), time.monotonic())

    def _command(self, velocity: FloatArray, hold: FloatArray | None) -> None:
        w = self._world()
        if np.any(velocity):
            R = w.ee_rotation()
            target = R if hold is None else np.asarray(hold, dtype=np.float64)
            twist = np.concatenate([velocity, ORIENTATION_GAIN * small_rotation_error(R, target)])
            velocity_step(w, twist, self.dt)
        # a zero command moves nothing: no orientation correction, no null-space drift
        if self.profile.sim.realtime:
            self._next_tick += self.dt
            delay = self._next_tick - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                self._next_tick = time.monotonic()

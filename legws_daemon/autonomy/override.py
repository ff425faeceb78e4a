"""The way back from the robot's guess: an override, and a hand-back without a jump.

An *override* is the operator holding the stick against the goal the robot moves toward —
the committed goal during assistance (before the gripper acted), the guessed goal while
``blend`` helps before the commit — with a deflection of at least
:data:`OVERRIDE_DEFLECTION`, at an angle whose cosine to the direction from the EE to that
goal is below :data:`OVERRIDE_COSINE` (more than 107°), for :data:`OVERRIDE_SECONDS`
without a break. A tick without input (the dead-man) counts neither way.

Whenever control comes back to the operator (an override, the cancel button), the command
then changes by at most :data:`HANDBACK_ACCELERATION` · dt per tick (:class:`HandBack`)
until it has caught up with the operator's — except to zero: a stop or the dead-man is
never ramped.
"""

from __future__ import annotations

import numpy as np

from legws_daemon.core.arbitration import against, slew
from legws_daemon.core.geometry import FloatArray

#: An override: the stick against the goal (cosine below this) ...
OVERRIDE_COSINE = -0.3
#: ... with at least this deflection ...
OVERRIDE_DEFLECTION = 0.5
#: ... for this long, seconds.
OVERRIDE_SECONDS = 0.4
#: The hand-back's bound on the change of the EE velocity, m/s² (0.025 m/s per tick at
#: 20 Hz: from the assisted 0.10 m/s to the operator's 0.05 m/s the other way in 6 ticks).
HANDBACK_ACCELERATION = 0.5


class OverrideDetector:
    """Sustained input against a direction: a goal's (the module docstring, the default
    thresholds), or the assisted motion's (:class:`~.cancel.CancelDetector`)."""

    def __init__(
        self,
        dt: float,
        cosine: float = OVERRIDE_COSINE,
        deflection: float = OVERRIDE_DEFLECTION,
        seconds: float = OVERRIDE_SECONDS,
        min_direction: float = 1e-9,
    ) -> None:
        self.dt = dt
        self.cosine, self.deflection, self.seconds = cosine, deflection, seconds
        self.min_direction = min_direction
        self._against = 0.0

    def reset(self) -> None:
        self._against = 0.0

    def update(self, axes: FloatArray | None, direction: FloatArray) -> bool:
        """One tick: ``axes`` the stick (``None``: no input, the count holds), ``direction``
        from the EE toward the goal; ``True`` once it has been held against long enough."""
        if axes is None:
            return False
        if against(axes, direction, self.cosine, self.deflection, self.min_direction):
            self._against += self.dt
        else:
            self._against = 0.0
        return self._against >= self.seconds - 1e-9


class HandBack:
    """The command's ramp after control came back (the module docstring)."""

    def __init__(self, dt: float, acceleration: float = HANDBACK_ACCELERATION) -> None:
        self.step = acceleration * dt
        self.active = False

    def start(self) -> None:
        self.active = True

    def stop(self) -> None:
        self.active = False

    def apply(self, previous: FloatArray, wanted: FloatArray) -> FloatArray:
        """This tick's velocity: ``wanted``, or on the way to it from ``previous`` (the
        velocity sent last tick) while the hand-back lasts. Zero is never ramped."""
        if not self.active:
            return wanted
        if not np.any(wanted):
            self.active = False
            return wanted
        v = slew(previous, wanted, self.step)
        if np.array_equal(v, wanted):
            self.active = False
        return v

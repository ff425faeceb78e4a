"""When the user takes control back from assistance: the cancel button, or the stick held
against the robot's motion."""

from __future__ import annotations

import math

import numpy as np

from legws_daemon.core.geometry import FloatArray

#: Cancel when the stick points against the assisted motion (cosine below this) ...
CANCEL_COSINE = -0.3
#: ... with at least this deflection ...
CANCEL_DEFLECTION = 0.5
#: ... for this long, seconds.
CANCEL_SECONDS = 0.4


class CancelDetector:
    """The user takes control back: cancel button, or the stick held against the motion."""

    def __init__(self, dt: float) -> None:
        self.dt = dt
        self._against = 0.0

    def reset(self) -> None:
        self._against = 0.0

    def update(self, axes: FloatArray | None, motion: FloatArray, button: bool) -> str | None:
        """Returns the reason to cancel (``button`` or ``opposed``), or ``None``.

        Args:
            axes: the stick's deflection, or ``None`` without input (the deadman pauses
                assistance; a paused tick counts neither way).
            motion: the EE's commanded velocity of the last tick, m/s.
            button: the cancel button.
        """
        if button:
            return "button"
        if axes is None:
            return None
        u = np.asarray(axes, dtype=np.float64)
        un = math.sqrt(float(u @ u))
        vn = math.sqrt(float(motion @ motion))
        if un >= CANCEL_DEFLECTION and vn > 1e-6 and float(u @ motion) / (un * vn) < CANCEL_COSINE:
            self._against += self.dt
        else:
            self._against = 0.0
        return "opposed" if self._against >= CANCEL_SECONDS - 1e-9 else None

"""When the user takes control back from assistance: the cancel button, or the stick held
against the robot's motion."""

from __future__ import annotations

from legws_daemon.autonomy.override import OverrideDetector
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
        # the override's mechanism, against the motion instead of a goal
        self._held = OverrideDetector(
            dt, CANCEL_COSINE, CANCEL_DEFLECTION, CANCEL_SECONDS, min_direction=1e-6
        )

    def reset(self) -> None:
        self._held.reset()

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
        return "opposed" if self._held.update(axes, motion) else None

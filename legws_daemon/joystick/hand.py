"""The operator's hand beyond the stick: the gripper button and the speed-scale button.

Both are *presses*, not states: a press of the gripper button toggles the gripper the
operator asks for (open → closed → open; a publisher's first request is ``closed``), a
press of the speed button steps the speed scale through :data:`SPEED_LEVELS` (1 → 0.5 →
0.25 → 1). The publisher multiplies the deflection and the rotation by the scale before it
sends them — the daemon sees a smaller deflection, inside the envelope like any other —
and sends the gripper request in every message (``buttons.gripper``) once the button was
first pressed (``null`` before: no request). Pure: the device readers (evdev, keyboard,
CAN) feed it whether each button is down, once per sample.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from legws_daemon.formats.messages import Buttons
from legws_daemon.joystick.publisher import Axes, Sample

#: The speed scales the speed button steps through, starting at the first.
SPEED_LEVELS: tuple[float, ...] = (1.0, 0.5, 0.25)


@dataclass
class HandState:
    """The gripper request and the speed scale, from the buttons' presses."""

    #: the gripper asked for (``True`` closed); ``None`` until the first press
    gripper: bool | None = None
    level: int = 0
    _down: dict[str, bool] = field(default_factory=dict, repr=False)

    @property
    def scale(self) -> float:
        return SPEED_LEVELS[self.level]

    def _pressed(self, name: str, down: bool) -> bool:
        """Whether ``down`` is a new press of ``name`` (it was up the last time)."""
        was = self._down.get(name, False)
        self._down[name] = down
        return down and not was

    def update(self, gripper_down: bool = False, speed_down: bool = False) -> None:
        """The buttons now: a press toggles the gripper or steps the speed scale."""
        if self._pressed("gripper", gripper_down):
            self.toggle_gripper()
        if self._pressed("speed", speed_down):
            self.step_speed()

    def toggle_gripper(self) -> None:
        """One press of the gripper button (a terminal's key: presses only, no releases)."""
        self.gripper = not self.gripper if self.gripper is not None else True

    def step_speed(self) -> None:
        """One press of the speed button."""
        self.level = (self.level + 1) % len(SPEED_LEVELS)

    def sample(self, axes: Axes, buttons: Buttons, turn: Axes | None = None) -> Sample:
        """What a device publishes: the deflection and the rotation times the speed scale,
        the gripper asked for in the buttons; no rotation (``None``, or zero) leaves it out
        of the message."""
        k = self.scale
        out = (axes[0] * k, axes[1] * k, axes[2] * k)
        buttons = buttons.model_copy(update={"gripper": self.gripper})
        if turn is None or not any(turn):
            return out, buttons
        return out, buttons, (turn[0] * k, turn[1] * k, turn[2] * k)

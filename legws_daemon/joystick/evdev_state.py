"""The pure part of ``legws joystick evdev``: evdev events + a mapping -> joystick samples.

:class:`DeviceState` is fed ``evdev.InputEvent`` objects with the (monotonic) time they were
read and answers, for any time, the :data:`~legws_daemon.joystick.publisher.Sample` to
publish. No I/O: the device side is :mod:`legws_daemon.joystick.evdev_input`.

Frames: events between two ``SYN_REPORT`` events are one frame, applied at the
``SYN_REPORT`` (a frame never shows half a stick move). ``SYN_DROPPED`` means the kernel's
buffer overflowed and events were lost: the events since the last ``SYN_REPORT`` and up to
the next one are discarded, relative axes are zeroed, and the state is *unknown* (absolute
axes at rest, every button up) until :meth:`DeviceState.sync` gives it the device's current
state (the reader does that at once from the device's ``absinfo`` and ``active_keys``).

Axes: an absolute axis keeps its last value. A relative axis (a SpaceMouse on EV_REL) is a
displacement reported while the cap is displaced; the kernel drops zero-valued relative
events, so a value counts for the axis's ``hold`` time (0.1 s unless the mapping says
otherwise) after the frame that carried it and is 0 after that. Each axis's value is
normalised to [-1, 1], then deadzone -> curve (:func:`shape`) -> scale -> invert; the
axes driving one base axis are summed, each base axis clipped to [-1, 1], the deflection
clipped to norm 1 (:func:`~legws_daemon.joystick.publisher.clip_norm`).

Hold-to-run: with an enable button in the mapping, a sample is the deflection only while one
of the enable buttons is held; otherwise it is zero with ``enable``, ``confirm`` and
``cancel`` all false: a confirm or cancel without the enable held is not sent (a stray press
of a button cannot commit or cancel). With ``enable = "none"`` every sample has
``enable = true``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from evdev import InputEvent, ecodes

from legws_daemon.formats.input_mapping import (
    EV_ABS,
    EV_KEY,
    EV_REL,
    AxisSpec,
    ButtonRef,
    InputMapping,
)
from legws_daemon.formats.messages import Buttons
from legws_daemon.joystick.hand import HandState
from legws_daemon.joystick.publisher import ZERO, Axes, Sample, clip_norm

#: (min, max) of an absolute axis, raw units.
AbsRange = tuple[int, int]

SYN_REPORT: int = ecodes.SYN_REPORT
SYN_DROPPED: int = ecodes.SYN_DROPPED
EV_SYN: int = ecodes.EV_SYN

#: What a device without input says: zero deflection, enable released.
NO_INPUT: Sample = (ZERO, Buttons(enable=False))


def shape(value: float, deadzone: float, exponent: float) -> float:
    """Deadzone and response curve of a normalised value, sign kept.

    ``|value|`` is clipped to 1; up to ``deadzone`` the result is exactly 0; above it the
    rest of the range is rescaled to [0, 1] and raised to ``exponent``. The result is
    continuous and monotone in ``value``, 0 at the deadzone's edge, ±1 at full deflection.
    """
    magnitude = min(1.0, abs(value))
    if magnitude <= deadzone:
        return 0.0
    out = ((magnitude - deadzone) / (1.0 - deadzone)) ** exponent
    return math.copysign(min(1.0, out), value)


def normalise_abs(raw: int, lo: int, hi: int, rest_min: bool) -> float:
    """A raw absolute value in [-1, 1] (a stick, ``rest_min=False``: the middle of
    [lo, hi] is 0) or in [0, 1] (a trigger, ``rest_min=True``: 0 at ``lo``); clipped."""
    if rest_min:
        return min(1.0, max(0.0, (raw - lo) / (hi - lo)))
    half = (hi - lo) / 2.0
    return min(1.0, max(-1.0, (raw - (lo + half)) / half))


@dataclass(frozen=True)
class DeviceIdentity:
    """What matching a device to a mapping looks at: its name, ids and capabilities."""

    name: str
    vendor: int
    product: int
    keys: frozenset[int] = frozenset()
    abs: frozenset[int] = frozenset()
    rel: frozenset[int] = frozenset()

    def has(self, etype: int, code: int) -> bool:
        table = {EV_KEY: self.keys, EV_ABS: self.abs, EV_REL: self.rel}.get(etype, frozenset())
        return code in table


def missing_capabilities(mapping: InputMapping, device: DeviceIdentity) -> list[str]:
    """Why the device cannot drive the mapping (empty: it can): an enable button it lacks,
    or that it has none of the mapped axes."""
    missing = [r.code for r in mapping.buttons.enable if not device.has(r.etype, r.number)]
    if not any(device.has(a.etype, a.number) for a in mapping.axis):
        missing.append("any of " + ", ".join(a.code for a in mapping.axis))
    return missing


def recognises(mapping: InputMapping, device: DeviceIdentity) -> bool:
    """Whether ``mapping`` is for this device: its name or ids are the mapping's, and it
    has the enable buttons and at least one mapped axis."""
    return mapping.device.recognises(
        device.name, device.vendor, device.product
    ) and not missing_capabilities(mapping, device)


class DeviceState:
    """The state of one device under one mapping; pure (the caller passes the times).

    Args:
        mapping: the validated mapping.
        absinfo: the device's range of each absolute axis (``(min, max)`` by code), used
            where the mapping gives none; an absolute axis with neither is inactive.
    """

    def __init__(self, mapping: InputMapping, absinfo: Mapping[int, AbsRange] | None = None):
        self.mapping = mapping
        self._ranges: dict[int, AbsRange] = {}
        self._axes = tuple(mapping.axis)
        self._enable = tuple(mapping.buttons.enable)
        self._confirm = tuple(mapping.buttons.confirm)
        self._cancel = tuple(mapping.buttons.cancel)
        self._gripper = tuple(mapping.buttons.gripper)
        self._speed = tuple(mapping.buttons.speed)
        #: the gripper request and the speed scale (the presses of those buttons)
        self.hand = HandState()
        self._turns = any(a.turns for a in mapping.axis)
        #: absolute codes the mapping reads (axes and trigger buttons)
        self.abs_codes = frozenset(
            [a.number for a in self._axes if a.etype == EV_ABS]
            + [b.number for b in self._buttons() if b.etype == EV_ABS]
        )
        self.key_codes = frozenset(b.number for b in self._buttons() if b.etype == EV_KEY)
        self.rel_codes = frozenset(a.number for a in self._axes if a.etype == EV_REL)
        self._abs: dict[int, int] = {}
        self._rel: dict[int, tuple[int, float]] = {}  # code -> (value, time of its frame)
        self._keys: set[int] = set()
        self._unarmed: set[int] = set()  # held at a fresh sync: ignored until released
        self._pending: list[InputEvent] = []
        self._discarding = False
        #: a SYN_DROPPED was seen and :meth:`sync` has not been called since
        self.needs_sync = False
        self.events = 0  # events fed
        self.frames = 0  # SYN_REPORTs applied
        self.dropped = 0  # SYN_DROPPED seen
        self.set_ranges(absinfo or {})

    def _buttons(self) -> tuple[ButtonRef, ...]:
        return self._enable + self._confirm + self._cancel + self._gripper + self._speed

    def set_ranges(self, absinfo: Mapping[int, AbsRange]) -> None:
        """The device's absolute ranges (the mapping's own ``min``/``max`` win); a range
        with ``min >= max`` is ignored (the axis stays inactive)."""
        ranges = {code: (lo, hi) for code, (lo, hi) in absinfo.items() if lo < hi}
        refs: list[AxisSpec | ButtonRef] = [*self._axes, *self._buttons()]
        for ref in refs:
            if ref.etype == EV_ABS and ref.min is not None and ref.max is not None:
                ranges[ref.number] = (ref.min, ref.max)
        self._ranges = ranges

    # -- input ---------------------------------------------------------------------------

    def feed(self, event: InputEvent, now: float) -> None:
        """One event, read at monotonic time ``now`` (s)."""
        self.events += 1
        if event.type == EV_SYN:
            if event.code == SYN_DROPPED:
                self._drop()
            elif event.code == SYN_REPORT:
                if self._discarding:
                    self._discarding = False
                else:
                    self._apply(now)
                self._pending.clear()
            return
        if not self._discarding and event.type in (EV_ABS, EV_REL, EV_KEY):
            self._pending.append(event)

    def feed_all(self, events: Iterable[InputEvent], now: float) -> None:
        for event in events:
            self.feed(event, now)

    def _apply(self, now: float) -> None:
        self.frames += 1
        for e in self._pending:
            if e.type == EV_ABS and e.code in self.abs_codes:
                self._abs[e.code] = e.value
            elif e.type == EV_REL and e.code in self.rel_codes:
                self._rel[e.code] = (e.value, now)
            elif e.type == EV_KEY and e.code in self.key_codes:
                if e.value:  # 1 pressed, 2 auto-repeat (still held)
                    self._keys.add(e.code)
                else:
                    self._keys.discard(e.code)
                    self._unarmed.discard(e.code)

    def _drop(self) -> None:
        self.dropped += 1
        self._pending.clear()
        self._discarding = True
        self.needs_sync = True
        self._abs.clear()  # unknown until sync: at rest, every button up
        self._rel.clear()
        self._keys.clear()

    def reset(self) -> None:
        """Everything at rest and every button up (the device is lost)."""
        self._abs.clear()
        self._rel.clear()
        self._keys.clear()
        self._unarmed.clear()

    def sync(
        self, abs_values: Mapping[int, int], keys_down: Iterable[int], *, fresh: bool = False
    ) -> None:
        """The device's current state: the absolute axes' values and the keys held.
        Relative axes are at rest.

        ``fresh``: the device was just opened (at start, or on reconnecting); a button held
        now counts only once it has been released and pressed again, so a button stuck
        down or held while the device is plugged in starts nothing. Without ``fresh``
        (after ``SYN_DROPPED``) held buttons count, except those still waiting for that
        release.
        """
        self._abs = {c: v for c, v in abs_values.items() if c in self.abs_codes}
        self._keys = {c for c in keys_down if c in self.key_codes}
        self._unarmed = set(self._keys) if fresh else self._unarmed & self._keys
        self._rel.clear()
        self.needs_sync = False

    # -- output --------------------------------------------------------------------------

    def _value(self, axis: AxisSpec, now: float) -> float:
        """The normalised value of one axis, before deadzone and curve; 0 if unknown."""
        code = axis.number
        if axis.relative:
            value, at = self._rel.get(code, (0, -math.inf))
            if now - at > axis.hold_time:
                return 0.0
            return min(1.0, max(-1.0, value / float(axis.full_scale or 1)))
        raw = self._abs.get(code)
        span = self._ranges.get(code)
        if raw is None or span is None:
            return 0.0
        return normalise_abs(raw, span[0], span[1], axis.rest == "min")

    def _pressed(self, ref: ButtonRef) -> bool:
        if ref.etype == EV_KEY:
            return ref.number in self._keys and ref.number not in self._unarmed
        raw = self._abs.get(ref.number)
        span = self._ranges.get(ref.number)
        if raw is None or span is None:
            return False
        return normalise_abs(raw, span[0], span[1], rest_min=True) >= ref.cutoff

    def deflection(self, now: float, turns: bool = False) -> Axes:
        """The mapped deflection at ``now`` (``turns``: the rotation axes'), whatever the
        enable button says."""
        sums = [0.0, 0.0, 0.0]
        for axis in self._axes:
            if axis.turns != turns:
                continue
            value = shape(self._value(axis, now), axis.deadzone, axis.exponent) * axis.scale
            sums[axis.index] += -value if axis.invert else value
        return clip_norm([min(1.0, max(-1.0, s)) for s in sums])

    def enabled(self) -> bool:
        """Whether an enable button is held (always, for a mapping with ``enable = "none"``)."""
        return not self._enable or any(self._pressed(b) for b in self._enable)

    def sample(self, now: float) -> Sample:
        """What to publish at ``now``: the deflection and buttons while enabled, else
        zero with ``enable``, ``confirm`` and ``cancel`` false."""
        if not self.enabled():
            return NO_INPUT
        self.hand.update(
            any(self._pressed(b) for b in self._gripper), any(self._pressed(b) for b in self._speed)
        )
        buttons = Buttons(
            enable=True if self._enable else None,  # None: the device has no such button
            confirm=any(self._pressed(b) for b in self._confirm),
            cancel=any(self._pressed(b) for b in self._cancel),
        )
        turn = self.deflection(now, turns=True) if self._turns else None
        return self.hand.sample(self.deflection(now), buttons, turn)

"""The operator's newest joystick sample, shared between the transport and the control loop.

The transport calls :meth:`JoystickInbox.offer` with raw payloads as they arrive; the loop
asks :meth:`JoystickInbox.poll` once per tick. A payload is *rejected* — never used, and it
does not refresh the deadman — for one of :data:`REJECTIONS`:

- ``invalid``: it does not validate (the field is in :attr:`JoystickInbox.last_error`);
- ``auth``: its session is keyed (:meth:`JoystickInbox.hello`, :mod:`.session_keys`) and
  its ``auth`` tag is missing or wrong, or it carries a tag for a session this daemon gave
  no key — checked first: such a message changes nothing, not even the session's ``seq``;
- ``stale_seq``: its ``seq`` is not above the last one of its session (out of order, or
  replayed). A publisher without a ``session`` id that starts over at ``seq`` 0 is a
  restart and accepted;
- ``not_operator``: another session holds the operator lease (:mod:`.lease`).

A session that never asked for a key (a schema-1 sender written elsewhere) is taken as
before: its id and ``seq`` are all it has, and anyone who sees its messages can copy them.
legws's own publishers key every session.

What the loop gets is the lease holder's newest sample if it arrived within the deadman
timeout and the holder holds the enable button; else nothing, and the robot stands still.
A goodbye (``bye``) is no input from the moment it arrives. Rejections and lease changes
are queued for the loop, which reports them as events (:meth:`take_report`).
"""

from __future__ import annotations

import threading
from collections import Counter, OrderedDict
from dataclasses import dataclass, field, replace
from typing import Literal, get_args

import numpy as np

from legws_daemon.autonomy.inputs import OperatorInput
from legws_daemon.daemon.lease import Lease, LeaseChange, SessionKey
from legws_daemon.daemon.session_keys import SessionKeys
from legws_daemon.errors import InputError
from legws_daemon.formats.messages import (
    JoystickMessage,
    parse,
    public_session_id,
    tag_matches,
)

#: Why a joystick message was not used.
Rejection = Literal["invalid", "auth", "stale_seq", "not_operator"]
REJECTIONS: tuple[Rejection, ...] = get_args(Rejection)
#: Why no input reaches the controller this tick.
NoInput = Literal["no_operator", "no_input", "enable_released"]
#: Sessions whose last ``seq`` is remembered (the least recently heard are forgotten).
MAX_SESSIONS = 256
#: The ``source`` of a session given the lease before it was heard from.
NOT_HEARD = "(not heard yet)"
#: Default grace after the deadman timeout before a silent operator loses the lease, s.
LEASE_GRACE = 0.5


@dataclass(frozen=True, slots=True)
class Sample:
    """A validated joystick message and the local monotonic time it arrived."""

    message: JoystickMessage
    received: float
    #: a confirm or cancel pressed in an earlier sample of the same holder that no tick
    #: polled (several samples between two ticks): a tap is not lost to the next sample
    confirm_pressed: bool = False
    cancel_pressed: bool = False

    @property
    def operator(self) -> OperatorInput:
        """The sample as the controller takes it."""
        m = self.message
        rotation = None if m.rotation is None else np.array(m.rotation, dtype=np.float64)
        return OperatorInput(
            np.array(m.axes, dtype=np.float64), m.buttons.confirm or self.confirm_pressed,
            m.buttons.cancel or self.cancel_pressed, self.received, m.seq, m.stamp,
            rotation, m.buttons.gripper,
        )  # fmt: skip


@dataclass(slots=True)
class RejectionTally:
    """Rejections of one reason since the last report: how many, and the last one's
    sender (``session``: its public id) and error."""

    count: int = 0
    source: str | None = None
    session: str | None = None
    error: str | None = None


@dataclass(slots=True)
class InputReport:
    """What happened to the input since the last :meth:`JoystickInbox.take_report`."""

    changes: list[LeaseChange] = field(default_factory=list)
    rejections: dict[Rejection, RejectionTally] = field(default_factory=dict)


def _steering(message: JoystickMessage) -> bool:
    """What claims a free lease: the enable button held (a deliberate act, whatever the
    stick says), or — from a publisher without one — a deflection or a button pressed."""
    b = message.buttons
    if message.bye or b.enable is False:
        return False
    return b.enable is True or any(message.axes) or b.confirm or b.cancel


class JoystickInbox:
    """Thread-safe: the lease and the operator's newest valid sample.

    Args:
        key: the key expression the samples come from (named in rejection reasons).
        timeout: the deadman timeout, s.
        grace: how much longer a silent operator keeps the lease, s.
        stall_after: the loop's stall threshold (:func:`~.ticker.stall_threshold`): a
            message that comes longer than this after the loop's last :meth:`poll` finds the
            daemon stalled — handled then as :meth:`stalled` (the loop may not have seen it
            yet), so the holder's silence during the daemon's own pause is never a
            ``timeout``. ``None``: only :meth:`stalled` says so.
    """

    def __init__(
        self,
        key: str = "joystick",
        timeout: float = 0.25,
        grace: float = LEASE_GRACE,
        stall_after: float | None = None,
    ) -> None:
        self.key = key
        self.timeout = timeout
        self.stall_after = stall_after
        self._polled: float | None = None  # the loop's last poll
        self._stall_seen = False  # a stall was handled since the last poll
        self._lock = threading.Lock()
        self._sample: Sample | None = None
        self._sample_polled = False  # a tick has polled the sample held
        self._last_seq: OrderedDict[SessionKey, int] = OrderedDict()
        self.lease = Lease(timeout, grace)
        self.keys = SessionKeys()
        self.accepted = 0  # the operator's messages taken (a goodbye included)
        self.ignored = 0  # valid, nobody's input: the lease free and the message not steering
        self.reasons: Counter[Rejection] = Counter()
        self.invalid_fields: Counter[str] = Counter()  # ``invalid`` by the field named
        self.last_error: str | None = None
        self._report = InputReport()

    @property
    def rejected(self) -> int:
        """Messages rejected so far, all reasons."""
        return sum(self.reasons.values())

    def refuse(self, err: InputError) -> None:
        """A payload refused before it was read (too large): counted as ``invalid``."""
        with self._lock:
            self._reject("invalid", None, str(err))
            self.invalid_fields[err.field or "payload"] += 1

    def offer(self, payload: bytes, now: float) -> Sample | None:
        """Validate one payload received at ``now``; keep it if it is the operator's newest.

        Returns the stored sample, or ``None`` when the payload was rejected or is not
        input (a goodbye, a message of nobody's while the lease is free).
        """
        try:
            message = parse(JoystickMessage, payload, self.key)
        except InputError as err:
            with self._lock:
                self._reject("invalid", None, str(err))
                self.invalid_fields[err.field or "payload"] += 1
            return None
        with self._lock:
            self._notice_stall(now)
            key = SessionKey(message.session, message.source)
            refused = self._unauthentic(message)
            if refused is not None:
                self._reject("auth", key, refused)
                return None
            last = self._last_seq.get(key)
            restart = message.session is None and message.seq == 0
            if last is not None and message.seq <= last and not restart:
                self._reject("stale_seq", key, f"seq {message.seq} after {last}")
                return None
            self._remember(key, message.seq)
            enabled = message.buttons.enabled
            steering = _steering(message)
            mine, changes = self.lease.offer(
                key, now, steering=steering, bye=message.bye, enabled=enabled
            )
            self._changed(changes)
            if not mine:
                if self.lease.holder is not None:
                    self._reject("not_operator", key, "another session holds the lease")
                else:
                    self.ignored += 1
                return None
            self.accepted += 1
            if message.bye:
                self._sample = None
                return None
            sample = Sample(message, now)
            earlier = self._sample
            if earlier is not None and not self._sample_polled and not changes:
                b = earlier.message.buttons
                sample = Sample(
                    message,
                    now,
                    confirm_pressed=earlier.confirm_pressed or b.confirm,
                    cancel_pressed=earlier.cancel_pressed or b.cancel,
                )
            self._sample, self._sample_polled = sample, False
            return sample

    def poll(self, now: float, *, tick: bool = True) -> tuple[Sample | None, NoInput | None]:
        """The input for a tick at ``now``: the operator's newest sample if it arrived within
        the timeout and enable is held, else ``None`` and why. ``tick=False``: only asked
        (a command's reply), the presses the sample carries still go to the next tick."""
        with self._lock:
            self._polled, self._stall_seen = now, False
            change = self.lease.expire(now)
            if change is not None:
                self._changed([change])
                self._sample = None
            sample, holder = self._sample, self.lease.holder
            if tick and sample is not None:
                # its earlier presses reach this tick or none, once
                self._sample_polled = True
                if sample.confirm_pressed or sample.cancel_pressed:
                    self._sample = replace(sample, confirm_pressed=False, cancel_pressed=False)
        if holder is None:
            return None, "no_operator"
        if sample is None or now - sample.received > self.timeout or now < sample.received - 1:
            return None, "no_input"
        if not sample.message.buttons.enabled:
            return None, "enable_released"
        return sample, None

    def latest(self, now: float) -> Sample | None:
        """The sample of :meth:`poll` alone."""
        return self.poll(now)[0]

    def release(self, now: float) -> LeaseChange | None:
        """The ``release`` command (see :mod:`.lease`)."""
        with self._lock:
            change = self.lease.release(now)
            self._changed([change] if change else [])
            self._sample = None
        return change

    def hello(self, session: str) -> tuple[bytes, str]:
        """The ``hello`` command: a fresh key for ``session`` and its public id (the reply
        goes to the asker only).

        Raises:
            InputError: the session has a key already, holds the lease, or was heard from
                (:meth:`SessionKeys.issue <.session_keys.SessionKeys.issue>`).
        """
        with self._lock:
            holder = self.lease.holder
            heard = SessionKey(session, "") in self._last_seq
            key = self.keys.issue(
                session, holder=holder.session if holder is not None else None, heard=heard
            )
            return key, public_session_id(session)

    def stalled(self, now: float) -> None:
        """The daemon stood still until ``now``: what it heard before is stale (the sample
        is dropped: the tick of a stall moves nothing) and the holder keeps the lease,
        heard as of the resume (:meth:`Lease.stall`: a lease freed by the daemon's own
        pause would go to whoever sends first after it)."""
        with self._lock:
            self._sample = None
            if not self._stall_seen:
                self._stall(now)

    def take_control(self, session: str, now: float) -> LeaseChange | None:
        """The ``take_control`` command: the session named holds the lease — by a
        publisher's ``session`` id, its public id (what status shows), or the ``source`` of
        one that sends no session id."""
        with self._lock:
            change = self.lease.take(self._known(session), now)
            if change is not None:
                self._changed([change])
                self._sample = None
        return change

    def operator(self) -> dict[str, str | None] | None:
        """The lease holder (``source``, ``session``: its public id), or ``None``."""
        with self._lock:
            holder = self.lease.holder
        return None if holder is None else dict(holder.describe())

    def take_report(self) -> InputReport:
        """Lease changes and rejections since the last call (for events)."""
        with self._lock:
            report, self._report = self._report, InputReport()
        return report

    def counts(self) -> dict[Rejection, int]:
        """Rejections so far by reason (every reason, zeros included)."""
        with self._lock:
            return {r: self.reasons[r] for r in REJECTIONS}

    def clear(self) -> None:
        """Forget the current sample (e.g. after a stop: the user must move the stick again)."""
        with self._lock:
            self._sample = None

    # --- under the lock ------------------------------------------------------------------
    def _stall(self, now: float) -> None:
        self._stall_seen = True
        self._sample = None
        self.lease.stall(now)

    def _notice_stall(self, now: float) -> None:
        """A message at ``now``, long after the loop's last poll: the daemon stood still."""
        polled = self._polled
        if self.stall_after is None or polled is None or self._stall_seen:
            return
        if now - polled > self.stall_after:
            self._stall(now)

    def _unauthentic(self, message: JoystickMessage) -> str | None:
        """Why ``message`` is not its session's own (``auth``), or ``None``."""
        session = message.session
        if session is None:
            return None if message.auth is None else "a tag without a session id"
        key = self.keys.key(session)
        if key is None:
            if message.auth is None and not self.keys.unknown(session):
                return None  # a session without a key: taken as before
            self.keys.mark_unknown(session)
            return "a tag for a session this daemon gave no key (restarted? forged?)"
        if message.auth is None:
            return "no tag: the session is keyed"
        if not tag_matches(key, message):
            return "wrong tag"
        return None

    def _known(self, ident: str) -> SessionKey:
        """The session with id (or public id) ``ident`` — heard from, or keyed and not heard
        yet — else the id-less one with that ``source``, else a session not heard yet."""
        heard = list(reversed(self._last_seq))
        for key in heard:
            if key.session is not None and ident in (key.session, key.public_id):
                return key
        for session in reversed(self.keys.sessions()):
            if ident in (session, public_session_id(session)):
                return SessionKey(session, NOT_HEARD)
        for key in heard:
            if key.session is None and key.source == ident:
                return key
        return SessionKey(ident, NOT_HEARD)

    def _reject(self, reason: Rejection, key: SessionKey | None, error: str) -> None:
        self.reasons[reason] += 1
        self.last_error = error if key is None else f"{key.source}: {error}"
        tally = self._report.rejections.setdefault(reason, RejectionTally())
        tally.count += 1
        tally.error = error
        tally.source = key.source if key is not None else None
        tally.session = key.public_id if key is not None else None

    def _remember(self, key: SessionKey, seq: int) -> None:
        self._last_seq[key] = seq
        self._last_seq.move_to_end(key)
        while len(self._last_seq) > MAX_SESSIONS:
            oldest = next(iter(self._last_seq))
            if oldest == self.lease.holder:
                self._last_seq.move_to_end(oldest)
                continue
            del self._last_seq[oldest]

    def _changed(self, changes: list[LeaseChange]) -> None:
        self._report.changes.extend(changes)

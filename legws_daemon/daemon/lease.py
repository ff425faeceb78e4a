"""Who steers: one operator at a time.

Every joystick publisher is a *session*: the random ``session`` id its messages carry
(chosen at each publisher start), or — for a publisher that sends none — its ``source``
label. At most one session holds the operator *lease*; only its messages move the robot.
A session id is no secret (every message shows it): what makes a session the publisher's
own is its key (:mod:`.session_keys`), checked before the lease sees a message. Status and
events name a session by its public id (:func:`~legws_daemon.formats.messages.
public_session_id`), never by its id.

- The lease is free at start. The first session that **steers** takes it: a message with
  the enable button held (even with the stick centred), or — from a publisher without an
  enable button — a deflection or a button press (a stream of zeros, or of messages with
  enable released, claims nothing).
- The holder keeps it while it is heard: each of its valid messages renews it, whatever
  the stick says (an operator resting with enable released still holds it).
- It ends when the holder says goodbye (``bye``: a publisher that stops), when the holder
  has not been heard for the deadman timeout plus a grace period (a publisher that died),
  or on the ``release`` command. A holder that lost it to silence takes it back with any
  message that is input (``resumed``: a network hiccup, the stick centred while the arm
  works) as long as nobody else took it meanwhile.
- When the daemon itself stood still (``stall``: its process was paused) the holder keeps
  it: the silence was the daemon's, not the holder's, and a lease freed by a pause would
  go to whoever sends first after it (on a busy machine, an attacker's stream would win
  the race). The holder is taken as heard at the resume; what it sent before is stale
  (the inbox drops it: zero velocity until its next message).
- The ``take_control`` command hands it to a named session at once (heard from yet or
  not; a session never heard from loses it after the timeout plus the grace).

Pure logic: the caller passes the (monotonic) time; :class:`~.inbox.JoystickInbox` locks.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from legws_daemon.formats.messages import public_session_id

#: Why the lease changed hands.
LeaseReason = Literal["first_input", "resumed", "goodbye", "timeout", "release", "take_control"]


@dataclass(frozen=True, slots=True, eq=False)
class SessionKey:
    """A publisher session: its ``session`` id, or its ``source`` label when it sends none."""

    session: str | None
    source: str

    @property
    def ident(self) -> tuple[str, str]:
        """What tells sessions apart (a label never equals an id of the other kind)."""
        return ("session", self.session) if self.session is not None else ("source", self.source)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, SessionKey) and self.ident == other.ident

    def __hash__(self) -> int:
        return hash(self.ident)

    @property
    def public_id(self) -> str | None:
        """The session as status and events name it (``None``: it has no session id)."""
        return None if self.session is None else public_session_id(self.session)

    def describe(self) -> dict[str, str | None]:
        """The wire form: ``{"source": ..., "session": <public id>}``."""
        return {"source": self.source, "session": self.public_id}


@dataclass(frozen=True, slots=True)
class LeaseChange:
    """The lease went from ``previous`` to ``operator`` (``None``: nobody) for ``reason``."""

    previous: SessionKey | None
    operator: SessionKey | None
    reason: LeaseReason


class Lease:
    """The operator lease (see the module docstring).

    Args:
        timeout: the deadman timeout, s.
        grace: how much longer than the timeout a silent holder keeps the lease, s.
    """

    def __init__(self, timeout: float, grace: float) -> None:
        if not (timeout > 0.0 and grace >= 0.0):
            raise ValueError(f"timeout {timeout!r} must be > 0 and grace {grace!r} >= 0")
        self.timeout = timeout
        self.grace = grace
        self.holder: SessionKey | None = None
        self.since: float | None = None  # when the holder got it
        self.heard: float | None = None  # when the holder was last heard (or got it)
        self.lapsed: SessionKey | None = None  # lost it to silence; nobody had it since

    @property
    def expires_after(self) -> float:
        """Seconds of silence after which the holder loses the lease."""
        return self.timeout + self.grace

    def expire(self, now: float) -> LeaseChange | None:
        """End a silent holder's lease (``timeout``); the change, or ``None``."""
        if self.holder is None or self.heard is None or now - self.heard <= self.expires_after:
            return None
        holder = self.holder
        change = self._set(None, now, "timeout")
        self.lapsed = holder
        return change

    def offer(
        self, key: SessionKey, now: float, *, steering: bool, bye: bool, enabled: bool = True
    ) -> tuple[bool, list[LeaseChange]]:
        """A valid message of ``key`` at ``now``: whether it is the operator's, and the
        changes it caused (an expiry first, then a claim or a goodbye).

        Args:
            steering: the message claims a free lease (see the module docstring).
            bye: the publisher's last message.
            enabled: the message is input (enable not released).
        """
        changes = [c for c in (self.expire(now),) if c is not None]
        if self.holder is None and not bye:
            if steering:
                changes.append(self._set(key, now, "first_input"))
            elif enabled and key == self.lapsed:
                changes.append(self._set(key, now, "resumed"))
        if self.holder != key:
            return False, changes
        self.holder, self.heard = key, now  # (a session given the lease before it was heard)
        if bye:
            changes.append(self._set(None, now, "goodbye"))
        return True, changes

    def stall(self, now: float) -> None:
        """The daemon stood still (``stall``): the holder keeps the lease, heard as of
        ``now`` (the resume), so the daemon's own pause never times it out; the lease does
        not change hands."""
        if self.holder is not None:
            self.heard = now

    def release(self, now: float) -> LeaseChange | None:
        """The ``release`` command: nobody holds it; the next session that steers takes it."""
        return None if self.holder is None else self._set(None, now, "release")

    def take(self, key: SessionKey, now: float) -> LeaseChange | None:
        """The ``take_control`` command: ``key`` holds it from now (``None`` if it did)."""
        if self.holder == key:
            self.heard = now
            return None
        return self._set(key, now, "take_control")

    def _set(self, key: SessionKey | None, now: float, reason: LeaseReason) -> LeaseChange:
        change = LeaseChange(self.holder, key, reason)
        self.holder = key
        self.lapsed = None
        self.since = self.heard = now if key is not None else None
        return change

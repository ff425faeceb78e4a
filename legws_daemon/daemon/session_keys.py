"""Session keys: what binds a joystick session to the publisher that opened it.

On the bench transport anyone who reaches the daemon's port sees every joystick message —
a session's id, its ``seq`` — and may publish its own. So a session id alone proves
nothing: a copy of it with a higher ``seq`` would steer as the lease holder. A publisher
therefore asks the daemon for a key before its first message (the ``hello`` command, a
zenoh query: the reply goes to the querier only, never to other subscribers), and tags
every message with HMAC-SHA256 under it
(:func:`~legws_daemon.formats.messages.auth_tag`). The daemon refuses a keyed session's
message without the right tag before the lease or the ``seq`` check sees it.

:class:`SessionKeys` is the daemon's table: at most :data:`MAX_KEYS` sessions, the oldest
evicted first (never the lease holder's). It refuses to key a session id twice, the lease
holder's, or one already heard from without a key (the caller says which: see
:meth:`JoystickInbox.hello <legws_daemon.daemon.inbox.JoystickInbox.hello>`) — each
would hand a session someone else opened to whoever asked. It also remembers (bounded) the
ids heard with a tag it has no key for (a daemon restarted under a running publisher, or a
forgery): those are never keyed and never taken unkeyed.

Pure logic; :class:`~legws_daemon.daemon.inbox.JoystickInbox` locks.
"""

from __future__ import annotations

import secrets
from collections import OrderedDict

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import SESSION_KEY_BYTES, public_session_id

#: Sessions keyed at most (the oldest that does not hold the lease is forgotten first).
MAX_KEYS = 64
#: Session ids remembered as heard with a tag this daemon has no key for.
MAX_UNKNOWN = 256


class SessionKeys:
    """Session id -> key, bounded (see the module docstring).

    Args:
        capacity: how many keys are kept.
    """

    def __init__(self, capacity: int = MAX_KEYS) -> None:
        if capacity < 1:
            raise ValueError(f"capacity {capacity!r} must be >= 1")
        self.capacity = capacity
        self._keys: OrderedDict[str, bytes] = OrderedDict()
        self._unknown: OrderedDict[str, None] = OrderedDict()
        self.issued = 0  # keys given out so far
        self.evicted = 0  # keys forgotten to make room

    def __len__(self) -> int:
        return len(self._keys)

    def __contains__(self, session: object) -> bool:
        return session in self._keys

    def key(self, session: str) -> bytes | None:
        """The key of ``session``, or ``None`` (not keyed here)."""
        return self._keys.get(session)

    def sessions(self) -> list[str]:
        """The keyed session ids, the most recently keyed last."""
        return list(self._keys)

    def unknown(self, session: str) -> bool:
        """Whether ``session`` was heard with a tag this daemon has no key for."""
        return session in self._unknown

    def mark_unknown(self, session: str) -> None:
        """``session`` was heard with a tag and no key here: it is never keyed."""
        self._unknown[session] = None
        self._unknown.move_to_end(session)
        while len(self._unknown) > MAX_UNKNOWN:
            self._unknown.popitem(last=False)

    def issue(self, session: str, *, holder: str | None, heard: bool) -> bytes:
        """A fresh random key for ``session``; the oldest non-holder makes room if full.

        Args:
            holder: the lease holder's session id (never keyed afresh, never evicted).
            heard: the daemon already heard ``session`` without a key.

        Raises:
            InputError: ``session`` already has a key, holds the lease, was heard from
                unkeyed, or was heard with a tag the daemon has no key for.
        """
        if session in self._keys:
            why = "it has a key already (a session is keyed once)"
        elif session == holder:
            why = "it holds the operator lease"
        elif heard:
            why = "it was heard from without a key (a session is keyed before its first message)"
        elif session in self._unknown:
            why = "it was heard with a tag this daemon gave no key for"
        else:
            why = None
        if why is not None:
            raise InputError(f"no key for session {public_session_id(session)}: {why}",
                             field="argument")  # fmt: skip
        while len(self._keys) >= self.capacity:
            oldest = next((s for s in self._keys if s != holder), None)
            if oldest is None:  # (capacity 1 and it is the holder's)
                raise InputError("no key: the table holds only the operator's", field="argument")
            del self._keys[oldest]
            self.evicted += 1
        key = secrets.token_bytes(SESSION_KEY_BYTES)
        self._keys[session] = key
        self.issued += 1
        return key

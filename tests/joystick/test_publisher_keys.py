"""The publisher keys its session: ``hello`` before its first message, every message tagged;
without a daemon it goes untagged and, once one answers, goes on in a fresh keyed session;
a restarted daemon (another ``started``) gets a fresh keyed session too, a forged status
does not.

The daemon side is the daemon's own inbox and ``hello`` answer on a loopback zenoh session.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import zenoh

from legws_daemon.daemon.inbox import JoystickInbox
from legws_daemon.daemon.service import answer_hello
from legws_daemon.formats.messages import HelloRequest, JoystickMessage, parse, parse_request
from legws_daemon.joystick.publisher import HELLO_RETRY, Publisher
from legws_daemon.transport.session import config_from_spec, open_session
from tests.joystick.helpers import KEY, ROBOT, dial_spec, listen_spec
from tests.net import free_port

COMMAND = f"legws/{ROBOT}/command"
STATUS = f"legws/{ROBOT}/status"


class Daemon:
    """The daemon's inbox behind a joystick subscriber and a ``hello`` queryable."""

    def __init__(self, session: zenoh.Session, started: float) -> None:
        self.session, self.started = session, started
        self.inbox = JoystickInbox(KEY)
        self.messages: list[JoystickMessage] = []
        self._entities: list[Any] = [
            session.declare_subscriber(KEY, self._on_joystick),
            session.declare_queryable(COMMAND, self._on_query),
        ]

    def _on_joystick(self, sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes()
        self.messages.append(parse(JoystickMessage, payload, KEY))
        self.inbox.offer(payload, time.monotonic())

    def _on_query(self, query: zenoh.Query) -> None:
        assert query.payload is not None
        request = parse_request(query.payload.to_bytes(), COMMAND)
        if not isinstance(request, HelloRequest):  # take_control, as the daemon does it
            assert request.command == "take_control" and request.argument is not None
            self.inbox.take_control(request.argument, time.monotonic())
            reply = {"ok": True, "command": "take_control", "operator": self.inbox.operator()}
            query.reply(COMMAND, json.dumps(reply).encode())
            return
        ok, body = answer_hello(self.inbox, request, self.started)
        if ok:
            query.reply(COMMAND, body)
        else:
            query.reply_err(body)

    def status(self, started: float | None = None) -> None:
        body = {"schema": 1, "started": self.started if started is None else started}
        self.session.put(STATUS, json.dumps(body).encode())

    def close(self) -> None:
        for e in self._entities:
            e.undeclare()


@contextmanager
def daemon(port: int, started: float = 1000.0) -> Iterator[Daemon]:
    with open_session(config_from_spec(listen_spec(port))) as session:
        d = Daemon(session, started)
        try:
            yield d
        finally:
            d.close()


def wait(what: object, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not what():  # type: ignore[operator]
        assert time.monotonic() < deadline, "not in time"
        time.sleep(0.01)


def publisher(port: int) -> Publisher:
    return Publisher(config_from_spec(dial_spec(port)), KEY, source="keyed")


def test_every_message_of_a_session_is_tagged_with_the_key_of_its_hello() -> None:
    port = free_port()
    with daemon(port) as d, publisher(port) as pub:
        assert pub.wait_matched(10.0)
        shown = pub.session_id  # what a status line compares with, taken before it is keyed
        for _ in range(5):
            pub.publish((0.0, 0.3, 0.0))
        wait(lambda: len(d.messages) == 5)
        assert pub.keyed
        assert all(m.auth is not None and m.session == pub.wire_session for m in d.messages)
        assert d.inbox.counts() == {"invalid": 0, "auth": 0, "stale_seq": 0, "not_operator": 0}
        assert d.inbox.operator() == {"source": "keyed", "session": pub.session_id}
        assert pub.session_id == shown != pub.wire_session  # status shows the public id only


def test_without_a_daemon_it_goes_untagged_then_on_in_a_fresh_keyed_session() -> None:
    port = free_port()
    with publisher(port) as pub:
        first = pub.wire_session
        assert pub.publish((0.0, 0.3, 0.0)).auth is None and not pub.keyed
        with daemon(port) as d:
            assert pub.wait_matched(10.0)
            time.sleep(HELLO_RETRY)
            wait(lambda: pub.publish((0.0, 0.3, 0.0)) is not None and pub.keyed)
            pub.publish((0.0, 0.3, 0.0))
            wait(lambda: any(m.auth is not None for m in d.messages))
            second = pub.wire_session
            assert second != first  # its id was out untagged: never keyed
            old = [m for m in d.messages if m.session == first]
            new = [m for m in d.messages if m.session == second]
            assert old and old[-1].bye  # the untagged session said goodbye
            assert new[0].seq == 0 and all(m.auth is not None for m in new)
            assert d.inbox.counts()["auth"] == 0


def test_a_restarted_daemon_gets_a_fresh_keyed_session_and_a_forged_status_does_not() -> None:
    port = free_port()
    with daemon(port, started=1000.0) as d, publisher(port) as pub:
        assert pub.wait_matched(10.0)
        pub.publish((0.0, 0.3, 0.0))
        keyed_as = pub.wire_session
        assert pub.keyed
        d.status(started=2000.0)  # not the daemon's own: a forged status
        time.sleep(0.2 + HELLO_RETRY)
        pub.publish((0.0, 0.3, 0.0))
        assert pub.wire_session == keyed_as  # the daemon that keyed it still answers
        d.started = 3000.0  # the daemon restarted (a new one knows no key)
        d.inbox = JoystickInbox(KEY)
        d.status()
        time.sleep(0.2 + HELLO_RETRY)
        wait(lambda: pub.publish((0.0, 0.3, 0.0)) is not None and pub.wire_session != keyed_as)
        sample = pub.publish((0.0, 0.3, 0.0))
        assert sample.seq == 1 and sample.session == pub.wire_session
        wait(lambda: d.messages[-1].seq == 1 and d.messages[-1].session == pub.wire_session)
        assert d.inbox.operator() == {"source": "keyed", "session": pub.session_id}


def test_take_control_keys_the_session_first() -> None:
    """The command shows the session's id: the key comes before it, or anyone who saw the
    command could ask for the lease holder's key first (the daemon keys no holder)."""
    port = free_port()
    with daemon(port) as d, publisher(port) as pub:
        assert pub.wait_matched(10.0)
        reply = pub.take_control()
        assert reply["operator"] == {"source": "(not heard yet)", "session": pub.session_id}
        assert pub.keyed and pub.wire_session in d.inbox.keys
        pub.publish((0.0, 0.3, 0.0))
        wait(lambda: d.inbox.accepted == 1)
        assert d.inbox.operator() == {"source": "keyed", "session": pub.session_id}

"""zenoh sessions for the daemon and its publishers: safe defaults, explicit configs.

The library's default configuration joins UDP multicast scouting and listens on every
interface — not for a robot. Sessions here are built from the hardware profile's
``[transport]`` table (loopback peer, multicast off) unless a JSON5 configuration file is
given for a real network (router/client, TLS, access control). A session must be closed
(a session left open with a callback subscriber hangs the process at exit): use
:func:`open_session` as a context manager.

A session that cannot open is one line without zenoh's source locations
(:func:`session_problem`): a listen endpoint another process holds is
``tcp/127.0.0.1:7447 is in use — another daemon?``.

zenoh's own log stays off the terminal as zenoh writes it. Its Rust side logs nowhere
unless ``zenoh.init_log_from_env_or`` (or ``try_init_log_from_env``) is called — which
legws never does: that log goes to standard output, coloured with escape sequences, whatever
``RUST_LOG`` says. Its Python side (the ``zenoh`` logger: an exception a callback raised,
with its traceback) is routed by :func:`route_zenoh_log`, which every :func:`open_session`
calls, into legws's log as one terminal-safe line (``zenoh: callback error: ValueError:
...``, the traceback only at DEBUG).
"""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import zenoh

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import MAX_PAYLOAD
from legws_daemon.formats.printable import safe_text
from legws_daemon.formats.profile import TransportSpec
from legws_daemon.formats.validation import read_text


def keys(robot: str) -> dict[str, str]:
    """The key expressions of one robot (``legws/<robot>/...``)."""
    base = f"legws/{robot}"
    return {
        "joystick": f"{base}/joystick",
        "status": f"{base}/status",
        "events": f"{base}/events",
        "command": f"{base}/command",
        "objects": f"{base}/objects",
    }


#: Retry period of connect endpoints, ms: first and longest. zenoh's default back-off grows
#: to 4 s, longer than the daemon waits for its bridge (``link.bridge_timeout``, 3 s), so
#: a bridge started before the daemon could miss it; capped, it dials twice a second.
RETRY_INIT_MS = 100
RETRY_MAX_MS = 500


def config_from_spec(spec: TransportSpec) -> zenoh.Config:
    """A zenoh configuration from a profile's transport table."""
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(spec.mode))
    cfg.insert_json5("scouting/multicast/enabled", json.dumps(spec.multicast_scouting))
    # no gossip either: a peer learns of no one but the endpoints it is given
    cfg.insert_json5("scouting/gossip/enabled", "false")
    cfg.insert_json5("listen/endpoints", json.dumps(list(spec.listen)))
    cfg.insert_json5("connect/endpoints", json.dumps(list(spec.connect)))
    retry = {"period_init_ms": RETRY_INIT_MS, "period_max_ms": RETRY_MAX_MS,
             "period_increase_factor": 2}  # fmt: skip
    cfg.insert_json5("connect/retry", json.dumps(retry))
    return cfg


#: Deepest nesting of objects and arrays accepted in a zenoh configuration file (a real
#: one nests 5 levels).
MAX_CONFIG_DEPTH = 32


def json5_depth(text: str) -> int:
    """The deepest nesting of ``{}``/``[]`` in JSON5 text (brackets in strings and comments
    do not count); linear, no recursion."""
    depth = deepest = 0
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if c in "\"'":
            i += 1
            while i < n and text[i] != c:
                i += 2 if text[i] == "\\" else 1
        elif text.startswith("//", i):
            i = text.find("\n", i)
            i = n if i < 0 else i
        elif text.startswith("/*", i):
            i = text.find("*/", i + 2)
            i = n if i < 0 else i + 1
        elif c in "{[":
            depth += 1
            deepest = max(deepest, depth)
        elif c in "}]":
            depth -= 1
        i += 1
    return deepest


def config_from_file(path: Path) -> zenoh.Config:
    """A zenoh configuration from a JSON5 file (``--zenoh-config``); errors name the file."""
    text = read_text(path, "zenoh config")  # bounded; one line for a missing or odd file
    depth = json5_depth(text)
    if depth > MAX_CONFIG_DEPTH:
        # zenoh's parser recurses per level: a deep enough file overflows its stack (SIGSEGV)
        raise InputError(
            f"invalid zenoh configuration: nested {depth} levels deep, at most "
            f"{MAX_CONFIG_DEPTH} allowed",
            source=str(path),
        )
    try:
        return zenoh.Config.from_json5(text)
    except Exception as err:  # zenoh raises its own error types for bad JSON5 or keys
        detail = (str(err).strip().splitlines() or [type(err).__name__])[0]
        raise InputError(f"invalid zenoh configuration: {detail}", source=str(path)) from None


#: zenoh's words for a listener it could not open: the endpoint and the cause (bracketed)
_LISTENER = re.compile(r"Can not create a new \w+ listener bound to (\S+?):?\s+\[(.*)\]", re.DOTALL)
#: a Rust source location zenoh appends to its errors (`` at /root/.cargo/...rs:61.``)
_RUST_SOURCE = re.compile(r"\s+at\s+\S+\.rs:\d+(:\d+)?\.?")
_OS_ERROR = re.compile(r"\s*\(os error \d+\)")
#: the address a cause starts with (``127.0.0.1:7447: ``, ``... listener on HOST:PORT: ``)
_CAUSE_PREFIX = re.compile(r"^(Can not create a new \w+ listener on )?\S+:\d+:\s*")
_IN_USE = ("Address already in use", "os error 98", "address in use")


def session_problem(err: BaseException) -> str:
    """What zenoh's error on opening a session says, in one line of the user's words.

    A listen endpoint already in use (another daemon on the same port, or any other
    process): ``tcp/127.0.0.1:7447 is in use — another daemon?``; another endpoint that
    cannot listen: ``cannot listen on ENDPOINT: CAUSE``; anything else: ``cannot open a
    zenoh session: ...``. Rust source paths and OS error numbers are left out.
    """
    text = str(err).strip() or type(err).__name__
    listener = _LISTENER.search(text)
    if listener is not None:
        endpoint, cause = listener.group(1), listener.group(2)
        if any(word in cause for word in _IN_USE):
            return f"{endpoint} is in use — another daemon?"
        cause = _CAUSE_PREFIX.sub("", _OS_ERROR.sub("", _RUST_SOURCE.sub("", cause))).strip()
        return f"cannot listen on {endpoint}: {cause[:1].lower()}{cause[1:]}"
    detail = _OS_ERROR.sub("", _RUST_SOURCE.sub("", text)).strip()
    detail = (detail.splitlines() or [type(err).__name__])[0].strip()
    return f"cannot open a zenoh session: {detail}"


#: zenoh's Python logger, and the legws logger its records are told on
ZENOH_LOGGER = "zenoh"
_log = logging.getLogger("legws.transport")


class _ZenohLog(logging.Handler):
    """A record of zenoh's as one line of legws's log: its message and, with an exception,
    the exception's type and the first line of its text (the traceback at DEBUG)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
            exc = record.exc_info[1] if record.exc_info else None
            if exc is not None:
                first = (str(exc).strip().splitlines() or [""])[0]
                text += f": {type(exc).__name__}" + (f": {first}" if first else "")
            _log.log(record.levelno, "zenoh: %s", safe_text(text))
            if exc is not None:
                _log.debug("zenoh: the traceback of that", exc_info=record.exc_info)
        except Exception:
            self.handleError(record)


def route_zenoh_log() -> None:
    """Tell zenoh's Python log records on the ``legws.transport`` logger, one safe line
    each, instead of letting them reach Python's last-resort handler (their tracebacks
    on stderr as they are). Idempotent; leaves zenoh's Rust log alone (off)."""
    logger = logging.getLogger(ZENOH_LOGGER)
    if not any(isinstance(h, _ZenohLog) for h in logger.handlers):
        logger.addHandler(_ZenohLog())
    logger.propagate = False


@contextmanager
def open_session(config: zenoh.Config) -> Iterator[zenoh.Session]:
    """Open a session and always close it; a session that cannot open is one
    :class:`InputError` line (:func:`session_problem`). zenoh's Python log goes to legws's
    (:func:`route_zenoh_log`)."""
    route_zenoh_log()
    try:
        session = zenoh.open(config)
    except Exception as err:
        problem = session_problem(err)
        field = None if problem.endswith("another daemon?") else "transport"
        raise InputError(problem, field=field) from None
    try:
        yield session
    finally:
        session.close()  # type: ignore[no-untyped-call]


def payload_bytes(payload: zenoh.ZBytes | None, source: str, limit: int = MAX_PAYLOAD) -> bytes:
    """A received payload's bytes, copied out of zenoh only when it is at most ``limit``
    bytes long: its size is read first (a 16 MiB joystick message is refused without a
    16 MiB copy).

    Raises:
        InputError: too large, naming ``source`` (the key).
    """
    if payload is None:
        return b""
    size = len(payload)
    if size > limit:
        raise InputError(f"payload of {size} bytes exceeds {limit}", source=source)
    return payload.to_bytes()

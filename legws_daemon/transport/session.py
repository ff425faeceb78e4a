"""zenoh sessions for the daemon and its publishers: safe defaults, explicit configs.

The library's default configuration joins UDP multicast scouting and listens on every
interface — not for a robot. Sessions here are built from the hardware profile's
``[transport]`` table (loopback peer, multicast off) unless a JSON5 configuration file is
given for a real network (router/client, TLS, access control). A session must be closed
(a session left open with a callback subscriber hangs the process at exit): use
:func:`open_session` as a context manager.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import zenoh

from legws_daemon.errors import InputError
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
#: to 4 s, longer than the daemon waits for its bridge (``sawyer.bridge_timeout``, 3 s), so
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


def config_from_file(path: Path) -> zenoh.Config:
    """A zenoh configuration from a JSON5 file (``--zenoh-config``); errors name the file."""
    read_text(path)  # one-line errors for a missing or unreadable file
    try:
        return zenoh.Config.from_file(str(path))
    except Exception as err:  # zenoh raises its own error types for bad JSON5 or keys
        detail = (str(err).strip().splitlines() or [type(err).__name__])[0]
        raise InputError(f"invalid zenoh configuration: {detail}", source=str(path)) from None


@contextmanager
def open_session(config: zenoh.Config) -> Iterator[zenoh.Session]:
    """Open a session and always close it."""
    try:
        session = zenoh.open(config)
    except Exception as err:
        detail = (str(err).strip().splitlines() or [type(err).__name__])[0]
        raise InputError(f"cannot open a zenoh session: {detail}", field="transport") from None
    try:
        yield session
    finally:
        session.close()  # type: ignore[no-untyped-call]

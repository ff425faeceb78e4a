"""Is a zenoh configuration authenticated? The check a real arm's daemon and bridge make.

A transport is *authenticated* when every endpoint it listens on or dials is TLS (or
QUIC, which is TLS), the peers prove who they are (mutual TLS, or user/password over
TLS), and an access control denies by default. Without that, any process that can reach
the port can steer the robot, command the bridge, or feed the daemon false joint
states (docs/reliability.md, threat model). ``legws secure init`` writes configurations
that pass.
"""

from __future__ import annotations

import json
from typing import Any

import zenoh

#: Link protocols that are TLS.
SECURE_PROTOCOLS = ("tls", "quic")


def _get(config: zenoh.Config, key: str) -> Any:
    try:
        return json.loads(config.get_json(key))
    except Exception:  # a key this zenoh does not know: treated as unset
        return None


def _endpoints(config: zenoh.Config, which: str) -> list[str]:
    """The endpoints of ``listen`` or ``connect`` for the configuration's mode."""
    value = _get(config, f"{which}/endpoints")
    if isinstance(value, dict):  # zenoh's per-mode form {"router": [...], "peer": [...]}
        mode = _get(config, "mode") or "peer"
        value = value.get(mode, [])
    return [str(e) for e in value] if isinstance(value, list) else []


def authentication_problem(config: zenoh.Config) -> str | None:
    """What makes ``config`` unauthenticated (``None``: it is authenticated).

    A peer or router (the daemon, the bridge) also needs an access control denying by
    default; a client only dials the daemon, whose access control decides what it gets.
    """
    endpoints = _endpoints(config, "listen") + _endpoints(config, "connect")
    if not endpoints:
        return "it has no listen or connect endpoint"
    plain = [e for e in endpoints if e.split("/", 1)[0] not in SECURE_PROTOCOLS]
    if plain:
        return f"endpoint {plain[0]} is not TLS (use tls/HOST:PORT)"
    protocols = _get(config, "transport/link/protocols")
    if isinstance(protocols, list) and set(protocols) - set(SECURE_PROTOCOLS):
        return f"transport/link/protocols allows {sorted(set(protocols) - {'tls', 'quic'})}"
    mtls = _get(config, "transport/link/tls/enable_mtls") is True
    usrpwd = bool(
        _get(config, "transport/auth/usrpwd/dictionary_file")
        or _get(config, "transport/auth/usrpwd/user")
    )
    if not (mtls or usrpwd):
        return "no authentication (transport/link/tls/enable_mtls or transport/auth/usrpwd)"
    if _get(config, "mode") == "client":
        return None  # it only dials: what reaches it is what the daemon's access control allows
    if _get(config, "access_control/enabled") is not True:
        return "access_control is not enabled"
    if _get(config, "access_control/default_permission") != "deny":
        return 'access_control/default_permission is not "deny"'
    return None


def describe(config: zenoh.Config) -> str:
    """One phrase for logs and status: authenticated or what it lacks."""
    problem = authentication_problem(config)
    return "authenticated" if problem is None else f"UNAUTHENTICATED: {problem}"

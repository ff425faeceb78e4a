"""Who may do what: the zenoh configurations of an authenticated deployment.

Built here, in one place, from the roles of :mod:`.pki`, so that the daemon's access control,
the bridge's and the clients' configurations cannot disagree. ``legws secure init`` writes
them; ``docs/reliability.md`` (threat model) states them in words; the tests run them.

The daemon is the hub: every other party dials it over mutual TLS and also presents a
user name and password. Its access control (default deny, both directions) lets

- the **operator** steer (joystick, object poses) and command (queries on the command key);
- the **operator**, **observer** and **safety** roles watch status and events;
- **every authenticated role** stop the robot, each on its own key
  ``legws/<robot>/stop/<role>``, so a stop names who sent it (the key is the
  authenticated role: nobody can publish on another role's stop key);
- the **bridge** publish joint states and receive the daemon's joint commands, its resume
  and the stops.

The bridge's own access control admits commands, resumes and stops only over a link
authenticated as the daemon (certificate common name ``legws-daemon``): a peer that holds
the daemon's port without the daemon's key cannot complete the TLS handshake (the bridge
verifies the daemon's certificate against the CA and the host name), and no other
certificate is valid for a server (:mod:`.pki`).
"""

from __future__ import annotations

from typing import Any

from legws_daemon.transport.pki import Role, common_name
from legws_daemon.transport.session import RETRY_INIT_MS, RETRY_MAX_MS

#: Roles that dial the daemon.
CLIENT_ROLES: tuple[Role, ...] = ("operator", "observer", "safety", "bridge")
#: Roles that may stop the robot (every authenticated one).
STOPPERS: tuple[Role, ...] = ("operator", "observer", "safety", "bridge")
#: Roles that watch status and events.
WATCHERS: tuple[Role, ...] = ("operator", "observer", "safety")


def _rule(rid: str, messages: list[str], flow: str, keys: list[str]) -> dict[str, Any]:
    return {
        "id": rid,
        "messages": messages,
        "flows": [flow],
        "permission": "allow",
        "key_exprs": keys,
    }


def stop_key_expr(role: str) -> str:
    """The key expression (any robot) on which ``role`` may stop."""
    return f"legws/*/stop/{role}"


def daemon_acl() -> dict[str, Any]:
    """The daemon's access control (subjects need the user name *and* the certificate)."""
    rules = [
        _rule("steer", ["put"], "ingress", ["legws/*/joystick", "legws/*/objects"]),
        _rule("command", ["query"], "ingress", ["legws/*/command"]),
        _rule(
            "announce-inputs",
            ["declare_subscriber"],
            "egress",
            ["legws/*/joystick", "legws/*/objects"],
        ),
        _rule("answer-commands", ["declare_queryable", "reply"], "egress", ["legws/*/command"]),
        _rule("watch", ["declare_subscriber"], "ingress", ["legws/*/status", "legws/*/events"]),
        _rule("telemetry", ["put"], "egress", ["legws/*/status", "legws/*/events"]),
        _rule("announce-stop", ["declare_subscriber"], "egress", ["legws/*/stop/*"]),
        *[_rule(f"stop-{r}", ["put"], "ingress", [stop_key_expr(r)]) for r in STOPPERS],
        _rule("bridge-state", ["put"], "ingress", ["legws/*/bridge/state"]),
        _rule(
            "bridge-listens",
            ["declare_subscriber"],
            "ingress",
            ["legws/*/bridge/command", "legws/*/bridge/resume", "legws/*/stop/*"],
        ),
        _rule(
            "bridge-command",
            ["put"],
            "egress",
            ["legws/*/bridge/command", "legws/*/bridge/resume", "legws/*/stop/*"],
        ),
        _rule("bridge-announce", ["declare_subscriber"], "egress", ["legws/*/bridge/state"]),
    ]
    rules_of: dict[Role, list[str]] = {
        "operator": ["steer", "command", "announce-inputs", "answer-commands"],
        "observer": [],
        "safety": [],
        "bridge": ["bridge-state", "bridge-listens", "bridge-command", "bridge-announce"],
    }
    for role in WATCHERS:
        rules_of[role] += ["watch", "telemetry"]
    for role in STOPPERS:
        rules_of[role] += [f"stop-{role}"]
        if role != "bridge":
            rules_of[role] += ["announce-stop"]
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": [
            {"id": r, "usernames": [r], "cert_common_names": [common_name(r)]} for r in CLIENT_ROLES
        ],
        "policies": [{"id": r, "rules": rules_of[r], "subjects": [r]} for r in CLIENT_ROLES],
    }


def bridge_acl() -> dict[str, Any]:
    """The bridge's access control: only the daemon's certificate may command it."""
    from_daemon = ["legws/*/bridge/command", "legws/*/bridge/resume", "legws/*/stop/*"]
    rules = [
        _rule("from-daemon", ["put"], "ingress", from_daemon),
        _rule("listen", ["declare_subscriber"], "egress", from_daemon),
        _rule("state", ["put"], "egress", ["legws/*/bridge/state"]),
        _rule("state-listener", ["declare_subscriber"], "ingress", ["legws/*/bridge/state"]),
    ]
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": [{"id": "daemon", "cert_common_names": [common_name("daemon")]}],
        "policies": [{"id": "daemon", "rules": [r["id"] for r in rules], "subjects": ["daemon"]}],
    }


def _closed() -> dict[str, Any]:
    """No multicast discovery and no gossip: a peer learns of no one but its endpoints."""
    return {"multicast": {"enabled": False}, "gossip": {"enabled": False}}


def _tls_link(certs: dict[str, str], side: str) -> dict[str, Any]:
    """TLS only, mutual: this party's key and certificate for the ``listen`` or ``connect``
    side, the CA that verifies the other party."""
    return {
        "protocols": ["tls"],
        "tls": {
            "root_ca_certificate": certs["ca"],
            f"{side}_private_key": certs["key"],
            f"{side}_certificate": certs["cert"],
            "enable_mtls": True,
            "close_link_on_expiration": True,
        },
    }


def daemon_config(listen: list[str], certs: dict[str, str], credentials: str) -> dict[str, Any]:
    """The daemon: peer, TLS only, mutual TLS + user/password, :func:`daemon_acl`.

    Args:
        listen: TLS endpoints (``tls/ADDRESS:PORT``).
        certs: absolute paths ``ca``, ``cert``, ``key``.
        credentials: absolute path of the ``user:password`` dictionary.
    """
    return {
        "mode": "peer",
        "listen": {"endpoints": listen},
        "connect": {"endpoints": []},
        "scouting": _closed(),
        "transport": {
            "link": _tls_link(certs, "listen"),
            "auth": {"usrpwd": {"dictionary_file": credentials}},
        },
        "access_control": daemon_acl(),
    }


def client_config(
    role: Role, connect: list[str], certs: dict[str, str], password: str
) -> dict[str, Any]:
    """A party dialling the daemon: the bridge as a peer with :func:`bridge_acl` and a
    short retry period; the others as clients (which fail at once, in one line, when the
    daemon is down or refuses them)."""
    config: dict[str, Any] = {
        "mode": "peer" if role == "bridge" else "client",
        "connect": {"endpoints": connect},
        "listen": {"endpoints": []},
        "scouting": _closed(),
        "transport": {
            "link": _tls_link(certs, "connect"),
            "auth": {"usrpwd": {"user": role, "password": password}},
        },
    }
    if role == "bridge":
        config["connect"]["retry"] = {
            "period_init_ms": RETRY_INIT_MS,
            "period_max_ms": RETRY_MAX_MS,
            "period_increase_factor": 2,
        }
        config["access_control"] = bridge_acl()
    return config

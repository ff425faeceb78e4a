"""What counts as an authenticated transport (the check a real arm's daemon makes)."""

from __future__ import annotations

import json
from typing import Any

import pytest
import zenoh

from legws_daemon.formats.profile import TransportSpec
from legws_daemon.transport.access import client_config, daemon_config
from legws_daemon.transport.security import authentication_problem, describe
from legws_daemon.transport.session import config_from_spec

CERTS = {"ca": "/x/ca.pem", "cert": "/x/c.pem", "key": "/x/k.pem"}


def _config(data: dict[str, Any]) -> zenoh.Config:
    return zenoh.Config.from_json5(json.dumps(data))


def _daemon() -> dict[str, Any]:
    return daemon_config(["tls/127.0.0.1:7447"], CERTS, "/x/credentials.txt")


def test_the_written_daemon_and_clients_pass() -> None:
    assert authentication_problem(_config(_daemon())) is None
    for role in ("operator", "observer", "safety", "bridge"):
        cfg = client_config(role, ["tls/robot:7447"], CERTS, "pw")  # type: ignore[arg-type]
        assert authentication_problem(_config(cfg)) is None
    assert describe(_config(_daemon())) == "authenticated"


def test_the_loopback_default_is_not_authenticated() -> None:
    problem = authentication_problem(config_from_spec(TransportSpec()))
    assert problem == "endpoint tcp/127.0.0.1:7447 is not TLS (use tls/HOST:PORT)"
    assert describe(config_from_spec(TransportSpec())).startswith("UNAUTHENTICATED: endpoint")


def _without(path: str) -> dict[str, Any]:
    cfg = _daemon()
    *parents, last = path.split("/")
    node = cfg
    for p in parents:
        node = node[p]
    del node[last]
    return cfg


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (lambda c: c["listen"].update(endpoints=[]), "no listen or connect endpoint"),
        (
            lambda c: c["listen"].update(endpoints=["tls/127.0.0.1:7447", "tcp/0.0.0.0:7448"]),
            "endpoint tcp/0.0.0.0:7448 is not TLS",
        ),
        (lambda c: c["transport"]["link"].update(protocols=["tls", "tcp"]), "allows ['tcp']"),
        (lambda c: c["access_control"].update(enabled=False), "access_control is not enabled"),
        (lambda c: c["access_control"].update(default_permission="allow"), 'is not "deny"'),
    ],
)
def test_each_missing_piece_is_named(change: Any, expected: str) -> None:
    cfg = _daemon()
    change(cfg)
    assert expected in (authentication_problem(_config(cfg)) or "")


def test_tls_without_peer_authentication_is_not_enough() -> None:
    cfg = _without("transport/auth")
    cfg["transport"]["link"]["tls"]["enable_mtls"] = False
    assert "no authentication" in (authentication_problem(_config(cfg)) or "")
    cfg["transport"]["link"]["tls"]["enable_mtls"] = True  # mutual TLS alone is enough
    assert authentication_problem(_config(cfg)) is None


def test_a_client_needs_no_access_control_of_its_own() -> None:
    cfg = client_config("operator", ["tls/robot:7447"], CERTS, "pw")
    assert "access_control" not in cfg
    assert authentication_problem(_config(cfg)) is None
    cfg["connect"]["endpoints"] = ["tcp/robot:7447"]
    assert "not TLS" in (authentication_problem(_config(cfg)) or "")

"""A listen endpoint another process holds: one line naming it, no zenoh source paths."""

from __future__ import annotations

import socket

import pytest

from legws_daemon.errors import InputError
from legws_daemon.formats.profile import TransportSpec
from legws_daemon.transport.session import config_from_spec, open_session, session_problem
from tests.net import free_port


def _listener(port: int) -> TransportSpec:
    # loopback, multicast scouting and gossip off (config_from_spec), nothing to connect to
    return TransportSpec(listen=[f"tcp/127.0.0.1:{port}"], connect=[])


def test_a_port_held_by_a_plain_socket_is_one_line() -> None:
    port = free_port()
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as held:
        held.bind(("127.0.0.1", port))
        held.listen()
        with pytest.raises(InputError) as info, open_session(config_from_spec(_listener(port))):
            pass
    assert str(info.value) == f"tcp/127.0.0.1:{port} is in use — another daemon?"


def test_a_port_held_by_another_session_is_one_line() -> None:
    port = free_port()
    with (
        open_session(config_from_spec(_listener(port))),
        pytest.raises(InputError) as info,
        open_session(config_from_spec(_listener(port))),
    ):
        pass
    assert str(info.value) == f"tcp/127.0.0.1:{port} is in use — another daemon?"
    with open_session(config_from_spec(_listener(port))):  # free again once closed
        pass


# zenoh 1.10's own words (with the paths of the machine it was built on)
_CARGO = "/root/.cargo/git/checkouts/zenoh-9c599d5ef3e0480e/cc83980/io"


@pytest.mark.parametrize(
    ("zenoh_says", "problem"),
    [
        (
            "Can not create a new TCP listener bound to tcp/127.0.0.1:7447: [127.0.0.1:7447: "
            f"Address already in use (os error 98) at {_CARGO}/zenoh-link-commons/src/tcp.rs:61.]"
            f" at {_CARGO}/zenoh-links/zenoh-link-tcp/src/unicast.rs:338.",
            "tcp/127.0.0.1:7447 is in use — another daemon?",
        ),
        (
            "Can not create a new UDP listener bound to udp/127.0.0.1:7447: [Can not create a "
            "new UDP listener on 127.0.0.1:7447: Address already in use (os error 98) at "
            f"{_CARGO}/zenoh-links/zenoh-link-udp/src/unicast.rs:418.] at "
            f"{_CARGO}/zenoh-links/zenoh-link-udp/src/unicast.rs:536.",
            "udp/127.0.0.1:7447 is in use — another daemon?",
        ),
        (
            "Can not create a new TCP listener bound to tcp/[::1]:7447: [[::1]:7447: Address "
            f"already in use (os error 98) at {_CARGO}/zenoh-link-commons/src/tcp.rs:61.] at "
            f"{_CARGO}/zenoh-links/zenoh-link-tcp/src/unicast.rs:338.",
            "tcp/[::1]:7447 is in use — another daemon?",
        ),
        (
            "Can not create a new TCP listener bound to tcp/192.0.2.1:7447: [192.0.2.1:7447: "
            f"Cannot assign requested address (os error 99) at {_CARGO}/zenoh-link-commons/src/"
            f"tcp.rs:61.] at {_CARGO}/zenoh-links/zenoh-link-tcp/src/unicast.rs:338.",
            "cannot listen on tcp/192.0.2.1:7447: cannot assign requested address",
        ),
        (
            "Unable to connect to any of [Single(tcp/127.0.0.1:54243)]. Timeout! at "
            f"{_CARGO}/../zenoh/src/net/runtime/orchestrator.rs:388.",
            "cannot open a zenoh session: Unable to connect to any of "
            "[Single(tcp/127.0.0.1:54243)]. Timeout!",
        ),
    ],
)
def test_what_zenoh_says_becomes_one_line_without_its_sources(
    zenoh_says: str, problem: str
) -> None:
    assert session_problem(RuntimeError(zenoh_says)) == problem


def test_an_address_no_interface_has_names_the_endpoint() -> None:
    spec = TransportSpec(listen=["tcp/192.0.2.1:7447"], connect=[])  # TEST-NET-1: nobody's
    with pytest.raises(InputError) as info, open_session(config_from_spec(spec)):
        pass
    assert str(info.value) == (
        "transport: cannot listen on tcp/192.0.2.1:7447: cannot assign requested address"
    )
    assert ".rs" not in str(info.value)

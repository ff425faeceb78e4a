"""The tests' loopback ports: each xdist worker its own share, below the ephemeral range."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from tests import net


def test_workers_share_the_ports_without_overlap(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PYTEST_XDIST_WORKER_COUNT", "4")
    shares = []
    for i in range(4):
        monkeypatch.setenv("PYTEST_XDIST_WORKER", f"gw{i}")
        shares.append(set(net.worker_ports()))
    assert all(len(s) >= 2000 for s in shares)
    assert len(set().union(*shares)) == sum(len(s) for s in shares)  # disjoint
    ephemeral = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()
    low = int(ephemeral[0])
    assert max(max(s) for s in shares) < low  # no outgoing connection takes one
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw2")
    port = net.free_port()
    assert port in shares[2] and port != net.free_port()  # never the same twice
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))  # free


def test_a_taken_port_is_skipped(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PYTEST_XDIST_WORKER_COUNT", "12")  # a share of 1000
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw11")
    share = net.worker_ports()
    taken = []
    try:
        for port in share:  # every one but the last taken by a listener
            if port == share[-1]:
                break
            s = socket.socket()
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                s.close()
                continue
            s.listen()
            taken.append(s)
        monkeypatch.setattr(net, "_given", set())
        assert net.free_port() == share[-1]
    finally:
        for s in taken:
            s.close()

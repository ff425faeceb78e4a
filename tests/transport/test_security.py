"""Security on loopback: only the operator's identity moves the robot.

The shipped configurations in ``hw_profiles/zenoh/`` are loaded through zenoh itself and
re-pointed at a test port, a test credentials file and certificates made by the shipped
``make-certs.sh`` in a temporary folder; their access-control rules are used unchanged.
A real ``legws daemon`` process runs on them and is watched from an *observer* session
(allowed to read status); then

- a peer without credentials (or with a wrong password, or without a client certificate)
  cannot connect, and its joystick messages never reach the daemon;
- the authenticated observer's joystick messages and commands are dropped by the ACL;
- the operator (``legws joystick replay --zenoh-config ...``) moves the arm and its
  commands are carried out.

Both daemon variants run: user/password over TCP and mutual TLS + user/password (where the
operator needs the right password *and* the right certificate). Further tests read the
shipped rules (default deny, only the operator steers, both daemon files agree), run the
``sawyer`` profile with the fake bridge connecting under its own identity, and check that a
real-hardware profile does not start without ``--allow-motion``.
Ports are chosen free at run time (:func:`tests.net.free_port`); every session is closed
and every wait is bounded.
"""

from __future__ import annotations

import json
import secrets
import shutil
import subprocess
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from legws_daemon.cli.main import run
from legws_daemon.errors import InputError
from legws_daemon.transport.session import keys, open_session
from tests.daemon.procs import LEGWS, REPO, Monitor, ee, env, ready, start, stop, write_profile
from tests.net import free_port

ZENOH_DIR = REPO / "hw_profiles" / "zenoh"
MAKE_CERTS = ZENOH_DIR / "make-certs.sh"
ROBOT = "sawyer_sim"
STICK = (0.0, 0.8, 0.0)  # +y at 0.8 of v_max (0.05 m/s): ~4 cm per second held


# --- configurations ------------------------------------------------------------------------
def shipped(name: str) -> dict[str, Any]:
    """A shipped JSON5 configuration as zenoh reads it (the full configuration, as JSON)."""
    loaded: dict[str, Any] = json.loads(str(zenoh.Config.from_file(str(ZENOH_DIR / name))))
    return loaded


def _write(path: Path, config: dict[str, Any]) -> Path:
    path.write_text(json.dumps(config, indent=1))
    return path


@dataclass(frozen=True)
class Deployment:
    """Test credentials (and certificates) for one daemon on one loopback port."""

    tmp: Path
    port: int
    tls: bool
    passwords: dict[str, str]

    @property
    def certs(self) -> Path:
        return self.tmp / "certs"

    def endpoint(self) -> str:
        return f"{'tls' if self.tls else 'tcp'}/127.0.0.1:{self.port}"

    def daemon_file(self) -> Path:
        """The shipped daemon configuration on this port, credentials and certificates."""
        cfg = shipped("daemon-secure.json5" if self.tls else "daemon-usrpwd.json5")
        cfg["listen"]["endpoints"] = [self.endpoint()]
        cfg["transport"]["auth"]["usrpwd"]["dictionary_file"] = str(self.tmp / "credentials.txt")
        if self.tls:
            tls = cfg["transport"]["link"]["tls"]
            tls["root_ca_certificate"] = str(self.certs / "ca.pem")
            tls["listen_private_key"] = str(self.certs / "daemon-key.pem")
            tls["listen_certificate"] = str(self.certs / "daemon.pem")
        return _write(self.tmp / "daemon.json5", cfg)

    def client(
        self,
        base: str,
        user: str | None,
        password: str | None = None,
        cert: str | None = None,
    ) -> dict[str, Any]:
        """A shipped client configuration (``operator.json5``, ``observer.json5``,
        ``bridge.json5``) dialling this daemon as ``user`` with ``cert``'s certificate;
        ``user=None`` drops the credentials, ``cert=None`` the client certificate."""
        cfg = shipped(base)
        cfg["connect"]["endpoints"] = [self.endpoint()]
        usrpwd = cfg["transport"]["auth"]["usrpwd"]
        usrpwd["user"] = user
        usrpwd["password"] = (password or self.passwords[user]) if user else None
        tls = cfg["transport"]["link"]["tls"]
        for field in ("root_ca_certificate", "connect_private_key", "connect_certificate"):
            tls[field] = None
        tls["enable_mtls"] = None
        if self.tls:
            tls["root_ca_certificate"] = str(self.certs / "ca.pem")
            tls["enable_mtls"] = cert is not None
            if cert is not None:
                tls["connect_private_key"] = str(self.certs / f"{cert}-key.pem")
                tls["connect_certificate"] = str(self.certs / f"{cert}.pem")
        return cfg

    def client_file(self, base: str, user: str, cert: str) -> Path:
        """:meth:`client` written to a file (for ``--zenoh-config``)."""
        return _write(self.tmp / f"{user}-{cert}.json5", self.client(base, user, cert=cert))


def deployment(tmp: Path, port: int, *, tls: bool) -> Deployment:
    """Fresh random passwords in a credentials file; certificates from make-certs.sh."""
    passwords = {name: secrets.token_urlsafe(12) for name in ("operator", "observer", "bridge")}
    lines = [f"{name}:{password}" for name, password in passwords.items()]
    (tmp / "credentials.txt").write_text("\n".join(lines) + "\n")
    if tls:
        made = subprocess.run(
            ["sh", str(MAKE_CERTS), str(tmp / "certs")],
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        assert made.returncode == 0, made.stderr
    return Deployment(tmp, port, tls, passwords)


# --- helpers ---------------------------------------------------------------------------------
@contextmanager
def session(config: dict[str, Any]) -> Iterator[zenoh.Session]:
    """A zenoh session on a configuration given as JSON; always closed."""
    with open_session(zenoh.Config.from_json5(json.dumps(config))) as s:
        yield s


def patient(config: dict[str, Any], seconds: float = 30.0) -> dict[str, Any]:
    """A client configuration that keeps dialling for ``seconds`` (the daemon is starting)."""
    config["connect"]["timeout_ms"] = int(seconds * 1000)
    return config


def hold_stick(put: Callable[[bytes], None], seconds: float, source: str) -> None:
    """Put valid joystick messages (``STICK``) at 50 Hz for ``seconds``."""
    end = time.monotonic() + seconds
    seq = 0
    while time.monotonic() < end:
        msg = {"schema": 1, "seq": seq, "stamp": time.time(), "axes": list(STICK), "source": source}
        put(json.dumps(msg).encode())
        seq += 1
        time.sleep(0.02)


def command(s: zenoh.Session, name: str) -> list[tuple[bool, dict[str, Any]]]:
    """Send a command; every reply as (ok, body) — none when nobody (visible) answers."""
    body = json.dumps({"schema": 1, "command": name}).encode()
    return [
        (True, json.loads(r.ok.payload.to_bytes()))
        if r.ok is not None
        else (False, json.loads(r.err.payload.to_bytes()))
        for r in s.get(keys(ROBOT)["command"], payload=body, timeout=5.0)
    ]


def recording(path: Path, seconds: float) -> Path:
    """A joystick recording for ``legws joystick replay``: ``STICK`` held, 40 Hz."""
    t0 = time.time()
    lines = [
        json.dumps(
            {"schema": 1, "seq": i, "stamp": t0 + i / 40, "axes": list(STICK), "source": "rec"}
        )
        for i in range(int(seconds * 40))
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


def replay(rec: Path, config: Path) -> subprocess.CompletedProcess[str]:
    """``legws joystick replay`` of ``rec`` with a zenoh configuration file."""
    return subprocess.run(
        [*LEGWS, "joystick", "replay", str(rec), "--profile", "sim", "--zenoh-config", str(config)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        env=env(),
    )


def assert_still(m: Monitor, before: np.ndarray, rejected: int) -> None:
    """The arm has not moved, the daemon saw no valid input and rejected nothing new."""
    time.sleep(0.4)  # deadman (0.25 s) plus a status period
    np.testing.assert_allclose(ee(m), before, atol=1e-6)
    last = m.latest()
    assert last is not None
    assert last["deadman"] is True
    assert last["rejected"] == rejected
    assert last["mode"] == "teleop"


# --- the tests -------------------------------------------------------------------------------
def allowed_subjects(acl: dict[str, Any], message: str, flow: str, key: str) -> set[str]:
    """The subjects some policy allows ``message`` on ``key`` in ``flow`` (exact key match)."""
    rules = {
        r["id"]
        for r in acl["rules"]
        if r["permission"] == "allow"
        and message in r["messages"]
        and flow in (r["flows"] or ["ingress", "egress"])
        and key in r["key_exprs"]
    }
    return {s for p in acl["policies"] if rules & set(p["rules"]) for s in p["subjects"]}


def test_shipped_configurations_are_closed_and_consistent() -> None:
    secure, plain = shipped("daemon-secure.json5"), shipped("daemon-usrpwd.json5")
    for cfg in (secure, plain):
        assert cfg["mode"] == "peer"
        assert cfg["scouting"]["multicast"]["enabled"] is False
        assert cfg["scouting"]["gossip"]["enabled"] is False
        assert cfg["transport"]["auth"]["usrpwd"]["dictionary_file"]
        acl = cfg["access_control"]
        assert acl["enabled"] is True
        assert acl["default_permission"] == "deny"
        assert not [r for r in acl["rules"] if r["permission"] != "allow"]
        assert allowed_subjects(acl, "put", "ingress", "legws/*/joystick") == {"operator"}
        assert allowed_subjects(acl, "query", "ingress", "legws/*/command") == {"operator"}
        assert allowed_subjects(acl, "reply", "egress", "legws/*/command") == {"operator"}
        watchers = allowed_subjects(acl, "declare_subscriber", "ingress", "legws/*/status")
        assert watchers == {"operator", "observer"}
        for key in ("status", "events"):  # nobody may publish the daemon's outputs
            assert allowed_subjects(acl, "put", "ingress", f"legws/*/{key}") == set()
    assert secure["transport"]["link"]["protocols"] == ["tls"]
    assert secure["transport"]["link"]["tls"]["enable_mtls"] is True
    assert all(e.startswith("tls/") for e in secure["listen"]["endpoints"])
    assert plain["transport"]["link"]["protocols"] == ["tcp"]
    # the same rules and policies; the TCP variant's subjects lack only the certificate names
    a, b = secure["access_control"], plain["access_control"]
    assert (a["rules"], a["policies"]) == (b["rules"], b["policies"])
    assert [{**s, "cert_common_names": None} for s in a["subjects"]] == b["subjects"]
    subjects = {s["id"]: s for s in a["subjects"]}
    for name in ("operator", "observer", "bridge"):
        client = shipped(f"{name}.json5")
        assert client["scouting"]["multicast"]["enabled"] is False
        assert client["transport"]["link"]["tls"]["enable_mtls"] is True
        assert client["transport"]["auth"]["usrpwd"]["user"] in subjects[name]["usernames"]
        assert subjects[name]["cert_common_names"] == [f"legws-{name}"]  # as make-certs.sh
        assert f"\nsign {name} legws-{name} " in MAKE_CERTS.read_text()
    assert not list(ZENOH_DIR.glob("*.pem"))  # no certificate or private key is shipped


@pytest.mark.slow
@pytest.mark.parametrize("tls", [False, True], ids=["usrpwd", "tls"])
def test_only_the_operator_moves_the_robot(tmp_path: Path, tls: bool) -> None:
    if tls and shutil.which("openssl") is None:
        pytest.skip("openssl is needed to make the test certificates")
    d = deployment(tmp_path, free_port(), tls=tls)
    log = tmp_path / "daemon.log"
    daemon = start(
        ["daemon", "--profile", "sim", "--scene", "desk", "--zenoh-config",
         str(d.daemon_file()), "--duration", "90"],
        log,
    )  # fmt: skip
    joystick = keys(ROBOT)["joystick"]
    try:
        with session(patient(d.client("observer.json5", "observer", cert="observer"))) as watcher:
            m = Monitor(watcher, ROBOT)
            try:
                assert m.wait_for(ready, 30), log.read_text()
                p0, rejected0 = ee(m), m.latest()["rejected"]  # type: ignore[index]

                # (b) no credentials, a wrong password, no client certificate: no session.
                refused = [
                    d.client("operator.json5", None, cert="operator"),
                    d.client("operator.json5", "operator", "wrong", cert="operator"),
                ]
                if tls:
                    refused.append(d.client("operator.json5", "operator", cert=None))
                for cfg in refused:
                    with (
                        pytest.raises(InputError, match="cannot open a zenoh session"),
                        session(cfg),
                    ):
                        pass  # client mode: opening fails at once
                # the same as a peer, which opens anyway and keeps retrying: nothing arrives
                peer = d.client("operator.json5", None, cert="operator")
                peer.update(mode="peer", listen={"endpoints": []})
                with session(peer) as intruder:
                    hold_stick(lambda b: intruder.put(joystick, b), 1.0, "intruder")
                    assert list(intruder.info.peers_zid()) == []
                assert_still(m, p0, rejected0)

                # (c) authenticated, not authorised: the observer's input and commands drop;
                # the daemon does not even show it the joystick subscriber
                rec = recording(tmp_path / "rec.jsonl", 1.0)
                observer = replay(rec, d.client_file("observer.json5", "observer", "observer"))
                assert observer.returncode == 0, observer.stderr
                assert "nobody subscribes" in observer.stderr
                hold_stick(lambda b: watcher.put(joystick, b), 1.0, "observer")
                assert command(watcher, "stop") == []
                assert_still(m, p0, rejected0)
                if tls:  # the operator's password with the observer's certificate
                    cfg = d.client("operator.json5", "operator", cert="observer")
                    with session(cfg) as wrong_cert:
                        assert (
                            len(list(wrong_cert.info.routers_zid()))
                            + len(list(wrong_cert.info.peers_zid()))
                            == 1
                        )  # connected ...
                        hold_stick(lambda b: wrong_cert.put(joystick, b), 1.0, "mixed")
                        assert command(wrong_cert, "stop") == []  # ... but not authorised
                    assert_still(m, p0, rejected0)

                # (a) the operator: the CLI publisher with the operator's configuration
                operator = d.client_file("operator.json5", "operator", "operator")
                user = replay(rec, operator)
                assert user.returncode == 0, user.stderr
                assert "nobody subscribes" not in user.stderr  # it saw the daemon's subscriber
                time.sleep(0.4)
                p1 = ee(m)
                assert p1[1] - p0[1] > 0.02, (p0, p1, user.stderr)  # it moved along +y
                assert m.latest()["rejected"] == rejected0  # type: ignore[index]
                with session(d.client("operator.json5", "operator", cert="operator")) as op:
                    replies = command(op, "stop")
                    assert [ok for ok, _ in replies] == [True], replies
                    assert m.wait_for(lambda m: (m.latest() or {}).get("mode") == "stopped", 5)
                    # events and status are two keys: their order on arrival is not fixed
                    assert m.wait_for(lambda m: "stop" in m.kinds(), 5)
            finally:
                m.close()
    finally:
        code, _ = stop(daemon)
    assert code == 0, log.read_text()


@pytest.mark.slow
def test_the_bridge_connects_under_its_own_identity(tmp_path: Path) -> None:
    """sawyer profile, user/password config: the fake bridge dials the daemon as 'bridge'."""
    d = deployment(tmp_path, free_port(), tls=False)
    bridge_cfg = d.client("bridge.json5", "bridge")
    bridge = start(
        ["bridge", "fake", "--profile", str(REPO / "hw_profiles" / "sawyer.toml"), "--scene",
         "desk", "--zenoh-config", str(_write(tmp_path / "bridge.json5", bridge_cfg))],
        tmp_path / "bridge.log",
    )  # fmt: skip
    daemon = None
    try:
        # the bridge retries every 0.5-1 s (bridge.json5): within the daemon's 3 s wait
        daemon = start(
            ["daemon", "--profile", "sawyer", "--scene", "desk", "--zenoh-config",
             str(d.daemon_file()), "--duration", "60", "--allow-motion"],
            tmp_path / "daemon.log",
        )  # fmt: skip
        joystick = keys("sawyer")["joystick"]
        with (
            session(patient(d.client("observer.json5", "observer"))) as watcher,
            session(d.client("operator.json5", "operator")) as op,
        ):
            m = Monitor(watcher, "sawyer")
            try:
                assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
                s0 = m.latest()
                assert s0 is not None
                assert (s0["adapter"], s0["fallback"], s0["fault"]) == ("sawyer", False, None)
                p0 = ee(m)
                hold_stick(lambda b: op.put(joystick, b), 1.0, "operator")
                time.sleep(0.4)
                assert ee(m)[1] - p0[1] > 0.02  # joint velocities reached the bridge
                assert m.latest()["mode"] == "teleop"  # type: ignore[index]
            finally:
                m.close()
    finally:
        try:
            code = stop(daemon)[0] if daemon is not None else 0
        finally:
            stop(bridge)  # even when the daemon's exit fails the test
    assert code == 0, (tmp_path / "daemon.log").read_text()


def test_a_real_arm_profile_needs_allow_motion(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Without --allow-motion a non-sim profile is refused before anything opens: one line,
    exit 2 — also when the profile would fall back to the stand-in."""
    fallback = write_profile(
        tmp_path, "sawyer", free_port(), {"fallback_to_sim = false": "fallback_to_sim = true"}
    )
    for profile in ("sawyer", str(fallback)):
        assert run(["daemon", "--profile", profile, "--duration", "1"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1
        assert err.startswith("legws: error: profile 'sawyer' drives the real arm")
        assert "--allow-motion" in err

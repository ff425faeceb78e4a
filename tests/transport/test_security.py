"""Security on loopback: an authenticated deployment from ``legws secure init``, attacked.

``legws secure init`` writes the CA, the identities and every party's configuration into a
temporary folder (on a free port); the tests run them unchanged against real ``legws
daemon`` and ``legws bridge fake`` processes and plain zenoh sessions, and show:

- a peer without credentials, with a wrong password or without a client certificate
  cannot open a session; nothing it sends arrives;
- an authenticated peer outside the operator role (the observer) cannot steer, command,
  move the arm through the bridge's keys, nor change what the daemon believes about the
  arm (its joint states are dropped), nor stop on another role's key;
- the operator steers and the arm moves;
- every authenticated role can stop (the ``stop`` event names it), and only the
  operator's ``reset`` starts the robot again;
- a listener without the daemon's key cannot pose as the daemon to the bridge;
- a real arm's daemon refuses an unauthenticated transport.

Ports are chosen free at run time; every session is closed and every wait is bounded.
"""

from __future__ import annotations

import copy
import json
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
from legws_daemon.formats.bridge_messages import bridge_keys, stop_key
from legws_daemon.transport.pki import Authority
from legws_daemon.transport.security import authentication_problem
from legws_daemon.transport.session import keys, open_session
from tests.daemon.procs import REPO, Monitor, ee, ready, start, stop, write_profile
from tests.net import free_port

ROBOT = "sawyer_sim"  # the sim profile's robot name
STICK = (0.0, 0.8, 0.0)  # +y at 0.8 of v_max (0.05 m/s): ~4 cm per second held
ROLES = ("daemon", "operator", "observer", "safety", "bridge")


# --- the deployment ----------------------------------------------------------------------------
def read_json5(path: Path) -> dict[str, Any]:
    """A configuration written by ``legws secure init`` (a comment header, then JSON)."""
    text = "\n".join(line for line in path.read_text().splitlines() if not line.startswith("//"))
    loaded: dict[str, Any] = json.loads(text)
    return loaded


@dataclass(frozen=True)
class Deployment:
    """The output of ``legws secure init`` on one loopback port."""

    root: Path
    port: int

    def config(self, role: str) -> dict[str, Any]:
        return read_json5(self.root / f"{role}.json5")

    def file(self, role: str) -> Path:
        return self.root / f"{role}.json5"

    def client(
        self, role: str, *, user: str | None = "", password: str | None = None, cert: str = ""
    ) -> dict[str, Any]:
        """``role``'s configuration, as written or with another ``user`` (``None``: no
        credentials), ``password`` or client certificate (``cert``; ``"-"``: none)."""
        cfg = copy.deepcopy(self.config(role))
        usrpwd = cfg["transport"]["auth"]["usrpwd"]
        if user is None:
            cfg["transport"]["auth"]["usrpwd"] = {}
        elif user:
            usrpwd["user"] = user
            usrpwd["password"] = self.config(user)["transport"]["auth"]["usrpwd"]["password"]
        if password is not None:
            usrpwd["password"] = password
        tls = cfg["transport"]["link"]["tls"]
        if cert == "-":
            tls["enable_mtls"] = False
            del tls["connect_private_key"], tls["connect_certificate"]
        elif cert:
            tls["connect_private_key"] = str(self.root / "certs" / f"{cert}-key.pem")
            tls["connect_certificate"] = str(self.root / "certs" / f"{cert}.pem")
        return cfg

    def write(self, name: str, cfg: dict[str, Any]) -> Path:
        path = self.root / f"test-{name}.json5"
        path.write_text(json.dumps(cfg))
        return path


def deployment(tmp: Path) -> Deployment:
    port = free_port()
    root = tmp / "secure"
    assert run(["secure", "init", str(root), "--port", str(port)]) == 0
    return Deployment(root, port)


@contextmanager
def session(config: dict[str, Any]) -> Iterator[zenoh.Session]:
    with open_session(zenoh.Config.from_json5(json.dumps(config))) as s:
        yield s


def patient(config: dict[str, Any], seconds: float = 30.0) -> dict[str, Any]:
    """A client configuration that keeps dialling for ``seconds`` (the daemon is starting)."""
    config["connect"]["timeout_ms"] = int(seconds * 1000)
    return config


def hold_stick(
    put: Callable[[bytes], None], seconds: float, source: str, axes: tuple[float, ...] = STICK
) -> None:
    """Put valid joystick messages (``axes``, enable held) at 50 Hz for ``seconds``."""
    end = time.monotonic() + seconds
    seq = 0
    while time.monotonic() < end:
        msg = {"schema": 1, "seq": seq, "stamp": time.time(), "axes": list(axes),
               "buttons": {"enable": True}, "source": source}  # fmt: skip
        put(json.dumps(msg).encode())
        seq += 1
        time.sleep(0.02)


def command(s: zenoh.Session, robot: str, name: str) -> list[tuple[bool, dict[str, Any]]]:
    """Send a command; every reply as (ok, body) — none when nobody (visible) answers."""
    body = json.dumps({"schema": 1, "command": name}).encode()
    return [
        (True, json.loads(r.ok.payload.to_bytes()))
        if r.ok is not None
        else (False, json.loads(r.err.payload.to_bytes()))
        for r in s.get(keys(robot)["command"], payload=body, timeout=5.0)
    ]


def stop_events(m: Monitor) -> list[dict[str, Any]]:
    with m._lock:
        return [e["detail"] for e in m.events if e["kind"] == "stop"]


def assert_still(m: Monitor, before: np.ndarray, mode: str = "teleop") -> None:
    """The arm has not moved and the daemon is not faulted."""
    time.sleep(0.4)  # deadman (0.25 s) plus a status period
    np.testing.assert_allclose(ee(m), before, atol=1e-6)
    last = m.latest()
    assert last is not None
    assert (last["mode"], last["fault"]) == (mode, None)


def allowed_subjects(acl: dict[str, Any], message: str, flow: str, key: str) -> set[str]:
    """The subjects some policy allows ``message`` on ``key`` in ``flow`` (exact key match)."""
    rules = {
        r["id"]
        for r in acl["rules"]
        if r["permission"] == "allow"
        and message in r["messages"]
        and flow in r["flows"]
        and key in r["key_exprs"]
    }
    return {s for p in acl["policies"] if rules & set(p["rules"]) for s in p["subjects"]}


# --- what `legws secure init` writes ------------------------------------------------------
def test_the_written_configurations_are_closed_and_agree(tmp_path: Path) -> None:
    d = deployment(tmp_path)
    daemon = d.config("daemon")
    assert daemon["listen"]["endpoints"] == [f"tls/127.0.0.1:{d.port}"]
    assert daemon["transport"]["link"]["protocols"] == ["tls"]
    assert daemon["transport"]["link"]["tls"]["enable_mtls"] is True
    acl = daemon["access_control"]
    assert (acl["enabled"], acl["default_permission"]) == (True, "deny")
    assert {r["permission"] for r in acl["rules"]} == {"allow"}
    assert allowed_subjects(acl, "put", "ingress", "legws/*/joystick") == {"operator"}
    assert allowed_subjects(acl, "put", "ingress", "legws/*/objects") == {"operator"}
    assert allowed_subjects(acl, "query", "ingress", "legws/*/command") == {"operator"}
    for role in ("operator", "observer", "safety", "bridge"):  # each on its own stop key only
        assert allowed_subjects(acl, "put", "ingress", f"legws/*/stop/{role}") == {role}
    assert allowed_subjects(acl, "put", "ingress", "legws/*/bridge/state") == {"bridge"}
    assert allowed_subjects(acl, "put", "egress", "legws/*/bridge/command") == {"bridge"}
    for key in ("status", "events", "bridge/command", "bridge/resume"):  # nobody sends these in
        assert allowed_subjects(acl, "put", "ingress", f"legws/*/{key}") == set()
    subjects = {s["id"]: s for s in acl["subjects"]}
    credentials = dict(
        line.split(":", 1) for line in (d.root / "credentials.txt").read_text().splitlines()
    )
    for role in ("operator", "observer", "safety", "bridge"):
        cfg = d.config(role)
        assert cfg["scouting"] == {"multicast": {"enabled": False}, "gossip": {"enabled": False}}
        assert cfg["connect"]["endpoints"] == [f"tls/127.0.0.1:{d.port}"]
        assert cfg["transport"]["link"]["tls"]["enable_mtls"] is True
        usrpwd = cfg["transport"]["auth"]["usrpwd"]
        assert credentials[usrpwd["user"]] == usrpwd["password"] and usrpwd["user"] == role
        assert subjects[role] == {
            "id": role, "usernames": [role], "cert_common_names": [f"legws-{role}"]
        }  # fmt: skip
        assert authentication_problem(zenoh.Config.from_file(str(d.file(role)))) is None
    bridge_acl = d.config("bridge")["access_control"]
    assert bridge_acl["subjects"] == [{"id": "daemon", "cert_common_names": ["legws-daemon"]}]
    assert allowed_subjects(bridge_acl, "put", "ingress", "legws/*/bridge/command") == {"daemon"}
    assert authentication_problem(zenoh.Config.from_file(str(d.file("daemon")))) is None
    for role in ROLES:  # keys for their owner only
        assert (d.root / "certs" / f"{role}-key.pem").stat().st_mode & 0o077 == 0
        assert d.file(role).stat().st_mode & 0o077 == 0
    assert not list((REPO / "hw_profiles").rglob("*.pem"))  # no key is shipped


def test_a_listener_without_the_daemons_key_cannot_pose_as_the_daemon(tmp_path: Path) -> None:
    """The bridge dials the daemon's port. Whoever holds that port with another identity's
    key (client-only usage, no host name) or with a certificate of another CA (named
    legws-daemon) never completes the handshake; the real daemon's key does."""
    d = deployment(tmp_path)
    other = Authority.create()
    fake = other.issue("daemon")
    (d.root / "certs" / "fake-daemon.pem").write_bytes(fake.cert_pem)
    (d.root / "certs" / "fake-daemon-key.pem").write_bytes(fake.key_pem)
    impostors = {"operator": "operator", "bridge": "bridge", "another CA": "fake-daemon"}
    for what, name in [*impostors.items(), ("the daemon", "daemon")]:
        port = free_port()
        listener = d.config("daemon")
        listener["listen"]["endpoints"] = [f"tls/127.0.0.1:{port}"]
        tls = listener["transport"]["link"]["tls"]
        tls["listen_private_key"] = str(d.root / "certs" / f"{name}-key.pem")
        tls["listen_certificate"] = str(d.root / "certs" / f"{name}.pem")
        bridge = d.config("bridge")
        bridge["connect"]["endpoints"] = [f"tls/127.0.0.1:{port}"]
        with session(listener), session(bridge) as b:
            deadline = time.monotonic() + (3.0 if name == "daemon" else 2.0)
            while time.monotonic() < deadline and not list(b.info.peers_zid()):
                time.sleep(0.05)
            connected = bool(list(b.info.peers_zid()))
        assert connected == (name == "daemon"), what


# --- the daemon and the operator ------------------------------------------------------------
@pytest.mark.slow
def test_only_the_operator_moves_the_robot_and_anyone_can_stop(tmp_path: Path) -> None:
    d = deployment(tmp_path)
    log = tmp_path / "daemon.log"
    daemon = start(
        ["daemon", "--profile", "sim", "--scene", "desk", "--zenoh-config", str(d.file("daemon")),
         "--duration", "90"],
        log,
    )  # fmt: skip
    joystick = keys(ROBOT)["joystick"]
    try:
        with session(patient(d.client("observer"))) as watcher:
            m = Monitor(watcher, ROBOT)
            try:
                assert m.wait_for(ready, 30), log.read_text()
                p0 = ee(m)
                assert m.latest()["transport"] == "authenticated"  # type: ignore[index]

                # no credentials, a wrong password, no client certificate: no session
                for cfg in (
                    d.client("operator", user=None),
                    d.client("operator", password="wrong"),
                    d.client("operator", cert="-"),
                ):
                    with (
                        pytest.raises(InputError, match="cannot open a zenoh session"),
                        session(cfg),
                    ):
                        pass  # client mode: opening fails at once
                # the same as a peer, which opens anyway and keeps retrying: nothing arrives
                peer = d.client("operator", user=None)
                peer.update(mode="peer")
                with session(peer) as intruder:
                    hold_stick(lambda b: intruder.put(joystick, b), 1.0, "intruder")
                    intruder.put(stop_key(ROBOT, "operator"), b"")
                    assert list(intruder.info.peers_zid()) == []
                assert_still(m, p0)

                # authenticated, not authorised: the observer's input and commands drop,
                # and so does a stop on another role's key
                hold_stick(lambda b: watcher.put(joystick, b), 1.0, "observer")
                assert command(watcher, ROBOT, "reset") == []
                watcher.put(stop_key(ROBOT, "operator"), b"")
                # the operator's password with the observer's certificate: both must match
                with session(d.client("operator", cert="observer")) as mixed:
                    hold_stick(lambda b: mixed.put(joystick, b), 1.0, "mixed")
                    assert command(mixed, ROBOT, "stop") == []
                assert_still(m, p0)
                assert stop_events(m) == []

                # the operator steers
                with session(d.client("operator")) as op:
                    hold_stick(lambda b: op.put(joystick, b), 1.0, "operator")
                    time.sleep(0.4)
                    p1 = ee(m)
                    assert p1[1] - p0[1] > 0.02, (p0, p1)  # it moved along +y

                    # anyone authenticated stops: the observer, then the safety role
                    watcher.put(stop_key(ROBOT, "observer"), b'{"schema": 1, "source": "me"}')
                    assert m.wait_for(lambda m: len(stop_events(m)) == 1, 5)
                    assert stop_events(m)[0]["by"] == "observer"
                    assert stop_events(m)[0]["source"] == "me"
                    assert m.wait_for(lambda m: m.latest()["mode"] == "stopped", 5)  # type: ignore[index]
                    with session(d.client("safety")) as safety:
                        safety.put(stop_key(ROBOT, "safety"), b"")
                        assert command(safety, ROBOT, "reset") == []  # it cannot start
                    assert m.wait_for(lambda m: len(stop_events(m)) == 2, 5)
                    assert stop_events(m)[1]["by"] == "safety"
                    # stopped: the stick moves nothing
                    p2 = ee(m)
                    hold_stick(lambda b: op.put(joystick, b), 0.6, "operator")
                    assert_still(m, p2, mode="stopped")
                    # only the operator starts it again
                    replies = command(op, ROBOT, "reset")
                    assert [ok for ok, _ in replies] == [True], replies
            finally:
                m.close()
    finally:
        code, _ = stop(daemon)
    assert code == 0, log.read_text()


# --- the bridge ---------------------------------------------------------------------------------
@pytest.mark.slow
def test_the_arm_obeys_only_the_daemon_and_the_daemon_believes_only_the_bridge(
    tmp_path: Path,
) -> None:
    """sawyer profile, fake bridge, both on the deployment's files. An authenticated
    observer publishing joint commands and joint states on the bridge's keys neither moves
    the arm nor changes the EE the daemon reports; the operator moves it; a stop from the
    safety role stops the bridge too, and the operator's reset resumes it."""
    d = deployment(tmp_path)
    profile = REPO / "hw_profiles" / "sawyer.toml"
    bridge = start(
        ["bridge", "fake", "--profile", str(profile), "--scene", "desk", "--zenoh-config",
         str(d.file("bridge"))],
        tmp_path / "bridge.log",
    )  # fmt: skip
    daemon = None
    bkeys = bridge_keys("sawyer")
    try:
        daemon = start(
            ["daemon", "--profile", "sawyer", "--scene", "desk", "--zenoh-config",
             str(d.file("daemon")), "--duration", "90", "--allow-motion"],
            tmp_path / "daemon.log",
        )  # fmt: skip
        joystick = keys("sawyer")["joystick"]
        with (
            session(patient(d.client("observer"))) as watcher,
            session(patient(d.client("operator"))) as op,
        ):
            m = Monitor(watcher, "sawyer")
            try:
                assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
                s0 = m.latest()
                assert s0 is not None
                assert (s0["adapter"], s0["fallback"], s0["fault"]) == ("sawyer", False, None)
                assert (s0["transport"], s0["insecure_transport"]) == ("authenticated", False)
                p0 = ee(m)

                # the attack: full-speed joint commands and false joint states, 200 Hz, 1.5 s
                hostile = {"schema": 1, "seq": 0, "stamp": 0.0, "mode": "joint_velocity",
                           "dq": [1.7, 1.3, 1.9, 1.9, 3.4, 3.4, 4.5], "ttl": 1.0,
                           "gripper": "closed"}  # fmt: skip
                fake_state = {"schema": 1, "seq": 0, "stamp": 0.0, "q": [0.5] * 7,
                              "dq": [0.0] * 7, "gripper": "open", "enabled": True,
                              "estop": True}  # fmt: skip
                end = time.monotonic() + 1.5
                seq = 0
                while time.monotonic() < end:
                    hostile.update(seq=seq, stamp=time.time())
                    fake_state.update(seq=seq, stamp=time.time())
                    watcher.put(bkeys["command"], json.dumps(hostile).encode())
                    watcher.put(bkeys["state"], json.dumps(fake_state).encode())
                    watcher.put(bkeys["resume"], b'{"schema": 1, "seq": 0, "stamp": 0.0}')
                    seq += 1
                    time.sleep(0.005)
                assert_still(m, p0)  # the arm did not move, the daemon saw no e-stop
                assert m.latest()["gripper_closed"] is False  # type: ignore[index]

                # the operator moves it
                hold_stick(lambda b: op.put(joystick, b), 1.0, "operator")
                time.sleep(0.4)
                p1 = ee(m)
                assert p1[1] - p0[1] > 0.02, (p0, p1)

                # the safety role stops daemon and bridge; the bridge holds the stop
                with session(d.client("safety")) as safety:
                    safety.put(stop_key("sawyer", "safety"), b'{"schema": 1, "reason": "t"}')
                assert m.wait_for(lambda m: [e["by"] for e in stop_events(m)] == ["safety"], 5)
                assert m.wait_for(lambda m: m.latest()["mode"] == "stopped", 5)  # type: ignore[index]
                p2 = ee(m)
                hold_stick(lambda b: op.put(joystick, b), 0.6, "operator")
                assert_still(m, p2, mode="stopped")
                replies = command(op, "sawyer", "reset")  # resumes the bridge, goes home
                assert [ok for ok, _ in replies] == [True], replies
                assert m.wait_for(lambda m: m.latest()["mode"] == "assist", 5)  # type: ignore[index]
                # assistance runs while the operator holds enable (the stick at rest)
                hold_stick(lambda b: op.put(joystick, b), 3.0, "operator", (0.0, 0.0, 0.0))
                assert np.linalg.norm(ee(m) - p2) > 0.01, (p2, ee(m))
                assert m.latest()["fault"] is None  # type: ignore[index]
            finally:
                m.close()
    finally:
        try:
            code = stop(daemon)[0] if daemon is not None else 0
        finally:
            stop(bridge)
    assert code == 0, (tmp_path / "daemon.log").read_text()


# --- a real arm and its transport ---------------------------------------------------------------
def test_a_real_arm_refuses_an_unauthenticated_transport(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before anything opens: one line, exit 2, saying what to configure."""
    profile = write_profile(tmp_path, "sawyer", free_port())
    plain = tmp_path / "tcp-usrpwd.json5"
    plain.write_text(
        json.dumps(
            {"mode": "peer", "listen": {"endpoints": [f"tcp/127.0.0.1:{free_port()}"]},
             "transport": {"auth": {"usrpwd": {"dictionary_file": str(tmp_path / "c.txt")}}},
             "access_control": {"enabled": True, "default_permission": "deny"}}
        )
    )  # fmt: skip
    for extra, expected in (
        ([], "endpoint tcp/127.0.0.1:"),
        (["--zenoh-config", str(plain)], "is not TLS"),
    ):
        args = ["daemon", "--profile", str(profile), "--allow-motion", "--duration", "1"]
        assert run([*args, *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1, err
        assert "drives the real arm but its transport" in err and expected in err
        assert "legws secure init" in err and "--insecure-transport" in err


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

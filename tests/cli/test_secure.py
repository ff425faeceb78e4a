"""``legws secure init`` and ``legws secure check`` through the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import zenoh

from legws_daemon.cli.main import run
from legws_daemon.transport.security import authentication_problem

FILES = ["bridge.json5", "certs", "credentials.txt", "daemon.json5", "observer.json5",
         "operator.json5", "safety.json5"]  # fmt: skip


def test_init_writes_a_deployment_and_check_accepts_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "dep"
    assert run(["secure", "init", str(out), "--host", "robot-pc.local", "--port", "7450"]) == 0
    assert sorted(p.name for p in out.iterdir()) == FILES
    assert len(list((out / "certs").iterdir())) == 12  # CA + 5 roles, key and certificate
    assert out.stat().st_mode & 0o077 == 0
    text = (out / "operator.json5").read_text()
    assert text.startswith("// legws operator:")
    assert "tls/robot-pc.local:7450" in text
    assert '"tls/0.0.0.0:7450"' in (out / "daemon.json5").read_text()  # --host: all interfaces
    for name in ("daemon", "operator", "bridge"):
        cfg = zenoh.Config.from_file(str(out / f"{name}.json5"))
        assert authentication_problem(cfg) is None
        assert run(["secure", "check", str(out / f"{name}.json5")]) == 0
    passwords = [line.split(":", 1)[1] for line in (out / "credentials.txt").read_text().split()]
    assert len(set(passwords)) == 4 and min(map(len, passwords)) >= 24
    capsys.readouterr()


def test_init_never_overwrites_and_bad_input_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "dep"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    for args, needle in (
        (["secure", "init", str(out)], "is not empty"),
        (["secure", "init", str(tmp_path / "n"), "--host", "bad host"], "neither an IP"),
        (["secure", "init", str(tmp_path / "n"), "--port", "0"], "0"),
    ):
        assert run(args) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err, err
    assert (out / "keep.txt").read_text() == "mine"
    assert not (tmp_path / "n").exists()


def test_check_names_what_is_missing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plain = tmp_path / "plain.json5"
    plain.write_text(json.dumps({"mode": "peer", "listen": {"endpoints": ["tcp/127.0.0.1:1"]}}))
    assert run(["secure", "check", str(plain)]) == 2
    err = capsys.readouterr().err
    expected = "not authenticated: endpoint tcp/127.0.0.1:1 is not TLS (use tls/HOST:PORT)"
    assert err == f"legws: error: {plain}: {expected}\n"

"""``legws_daemon.client`` against the real daemon (processes, zenoh loopback), and the
example in ``examples/`` run as a lab would run it."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from legws_daemon.client import Client, CommandRefusedError
from legws_daemon.errors import InputError
from legws_daemon.formats.messages import Buttons
from tests.daemon.procs import REPO, env, start, stop, write_profile
from tests.net import free_port


def test_no_daemon_is_one_error_naming_the_key_and_the_endpoint(tmp_path: Path) -> None:
    port = free_port()
    with Client.from_profile(write_profile(tmp_path, "sim", port)) as client:
        with pytest.raises(InputError) as err:
            client.status(timeout=0.3)
        assert str(err.value) == (
            f"no status from the daemon on legws/sawyer_sim/status within 0.3 s (dialled "
            f"tcp/127.0.0.1:{port}): is it running, for this robot, listening there?"
        )
        with pytest.raises(InputError, match="command"):  # does not validate: nothing sent
            client.command("fly")
    with pytest.raises(Exception, match="not open"):
        client.status()


@pytest.mark.slow
def test_a_client_reads_status_and_events_sends_commands_and_the_example_drives_a_pick(
    tmp_path: Path,
) -> None:
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    before = time.time()
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--duration", "120"],
        tmp_path / "daemon.log",
    )
    try:
        with Client.from_profile(profile) as client:
            status = client.status(timeout=30)
            assert status.robot == "sawyer_sim" and status.mode == "teleop"
            assert status.started is not None and before <= status.started <= status.stamp
            nxt = client.next_status(timeout=2)
            assert nxt is not None and nxt.seq > status.seq
            assert client.wait_for(lambda s: s.tick > status.tick + 5, timeout=5) is not None
            reply = client.command("status")
            assert reply.ok and reply.detail["robot"] == "sawyer_sim"
            with pytest.raises(CommandRefusedError, match="catalog"):
                client.command("load_scene", "../../etc/passwd")
            refused = client.command("load_scene", "nowhere", check=False)
            assert not refused.ok and refused.error
            # the joystick on the client's transport: it steers, and the events say so
            with client.joystick("client-test") as stick:
                for _ in range(10):
                    stick.publish((0.0, 0.5, 0.0), Buttons(enable=True))
                    time.sleep(0.05)
            operators = [e for e in client.events(timeout=2.0) if e.kind == "operator"]
            assert operators and operators[0].detail["operator"]["source"].startswith(
                "client-test:"
            )

        # the loopback configuration of docs/messages.md, as printed there, on this port
        doc = (REPO / "docs" / "messages.md").read_text()
        code = doc.split("**Connecting.**", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]
        assert "tcp/127.0.0.1:7447" in code
        snippet = subprocess.run(
            [sys.executable, "-c", code.replace("127.0.0.1:7447", f"127.0.0.1:{port}")],
            capture_output=True, text=True, timeout=60, check=False, env=env(),
        )  # fmt: skip
        assert snippet.returncode == 0, snippet.stderr
        assert snippet.stdout.strip() == "teleop"

        example = subprocess.run(
            [sys.executable, str(REPO / "examples" / "drive_pick.py"), str(profile), "white_mug"],
            capture_output=True, text=True, timeout=120, check=False, env=env(),
        )  # fmt: skip
        assert example.returncode == 0, example.stderr
        lines = example.stdout.splitlines()
        assert lines[0].startswith("daemon up since 1") and "white_mug" in lines[0]
        kinds = [line.split(" ", 1)[0] for line in lines[1:]]
        task = [k for k in kinds if k in ("commit", "stage_done", "task_done")]
        assert task == ["commit", "stage_done", "task_done"], lines
        assert "'goal': 'white_mug'" in next(x for x in lines if x.startswith("commit"))
    finally:
        code, _ = stop(daemon)
    assert code == 0

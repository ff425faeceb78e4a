"""Publishers that check and tell, against the real daemon (processes, zenoh loopback).

- ``sim-user --goal cereal`` on ``desk``: one line naming the decision's targets, exit 2 —
  not "going for cereal" and zeros for ever;
- no daemon where the profile points: one line naming the status key and the endpoint;
- while they run, the publishers' terminal shows what the daemon does (a pipe gets a line
  per change; the keyboard's own line on a terminal carries it).
"""

from __future__ import annotations

import json
import os
import pty
import select
import subprocess
import time
from pathlib import Path

import pytest

from tests.daemon.procs import LEGWS, REPO, env, monitor, ready, start, stop, write_profile
from tests.net import free_port

ROBOT = "sawyer_sim"


def run(args: list[str], timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*LEGWS, *args], capture_output=True, text=True, timeout=timeout, check=False, env=env()
    )


def recording(tmp_path: Path, count: int = 20) -> Path:
    path = tmp_path / "rec.jsonl"
    message = {"schema": 1, "axes": [0.0, 0.3, 0.0], "source": "rec"}
    lines = [json.dumps({**message, "seq": i, "stamp": 1000.0 + 0.05 * i}) for i in range(count)]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.slow  # ~12 s: three publishers, each waiting in vain
def test_no_daemon_is_one_line_saying_where_it_looked(tmp_path: Path) -> None:
    port = free_port()  # nobody listens here
    profile = write_profile(tmp_path, "sim", port)
    looked = (
        f"legws: error: no status from the daemon on legws/{ROBOT}/status within 1 s (dialled "
        f"tcp/127.0.0.1:{port}): is it running, for this robot, listening there?"
    )
    for args in (
        ["joystick", "sim-user", "--goal", "white_mug"],
        ["joystick", "replay", str(recording(tmp_path))],
    ):
        done = run([*args, "--profile", str(profile), "--wait-daemon", "1", "--duration", "30"])
        assert done.returncode == 2, done.stderr
        assert done.stderr.strip().splitlines() == [looked], done.stderr
        assert "going for" not in done.stderr
    # a longer wait says that it waits, and where, before it gives up
    done = run(["joystick", "sim-user", "--profile", str(profile), "--wait-daemon", "3"])
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"legws: waiting up to 3 s for the daemon's status on legws/{ROBOT}/status (dialled "
        f"tcp/127.0.0.1:{port})",
        looked.replace("within 1 s", "within 3 s"),
    ], done.stderr


@pytest.mark.slow
def test_publishers_check_the_goal_and_show_the_daemon(tmp_path: Path) -> None:
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    daemon = start(
        ["daemon", "--profile", str(profile), "--scene", "desk", "--duration", "120"],
        tmp_path / "daemon.log",
    )
    try:
        with monitor(port, ROBOT) as m:
            assert m.wait_for(ready, 30), (tmp_path / "daemon.log").read_text()
            wrong = run(["joystick", "sim-user", "--profile", str(profile), "--goal", "cereal",
                         "--duration", "30"])  # fmt: skip
            assert wrong.returncode == 2, wrong.stderr
            assert wrong.stderr.strip().splitlines()[-1] == (
                "legws: error: --goal: cereal is not a target of decision 1 (stage pick); its "
                "targets: black_stapler, maroon_pen_cup, white_mug"
            ), wrong.stderr
            assert "going for" not in wrong.stderr and "Traceback" not in wrong.stderr

            # a replay through a pipe: a line per change of what the daemon does
            played = run(["joystick", "replay", str(recording(tmp_path)), "--profile",
                          str(profile)])  # fmt: skip
            assert played.returncode == 0, played.stderr
            said = [x for x in played.stderr.splitlines() if x.startswith("legws: daemon: ")]
            assert said, played.stderr
            assert said[0].startswith("legws: daemon: teleop · stage pick · top "), said
            assert any(" · operator replay:" in x and "(you)" in x for x in said), said
            assert all(" · deadman " in x for x in said)

            # the keyboard on a terminal: its own line carries the daemon's
            master, slave = pty.openpty()
            try:
                kb = subprocess.Popen(
                    [*LEGWS, "joystick", "keyboard", "--profile", str(profile)],
                    cwd=REPO, stdin=slave, stdout=subprocess.DEVNULL, stderr=slave, env=env(),
                )  # fmt: skip
                shown = ""
                deadline = time.monotonic() + 30
                try:
                    os.write(master, b"w")
                    # steering: the daemon's part names this keyboard as the operator
                    while "(you) · deadman off" not in shown and time.monotonic() < deadline:
                        if select.select([master], [], [], 0.5)[0]:
                            shown += os.read(master, 65536).decode(errors="replace")
                        os.write(master, b"w")
                    os.write(master, b"q")
                    assert kb.wait(20) == 0
                finally:
                    if kb.poll() is None:
                        kb.kill()
                        kb.wait(5)
            finally:
                os.close(master)
                os.close(slave)
            assert "x +1.00  y +0.00  z +0.00  run  | teleop · stage pick · top " in shown
            assert " · operator keyboard:" in shown, shown[-400:]
    finally:
        code, _ = stop(daemon)
    assert code == 0

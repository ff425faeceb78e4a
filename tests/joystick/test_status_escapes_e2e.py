"""A hostile daemon's status cannot act on the publisher's terminal (real processes, zenoh
on loopback).

A fake daemon — a zenoh session listening on a loopback port — publishes statuses whose
stage, goals, commit, phase, operator source and fault hold escape sequences (CSI, OSC,
DCS), C0/C1 controls, bidirectional controls, zero-width characters and line separators
(:func:`tests.reliability.escape_corpus.hostile_texts`); a real ``legws joystick sim-user``
steers against it through a pipe. What it prints holds none of those characters: each is
shown as a visible escape.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import zenoh

from legws_daemon.errors import InputError
from legws_daemon.formats.messages import StatusMessage, parse
from legws_daemon.formats.printable import safe_text
from legws_daemon.joystick.daemon_status import NAME_LIMIT, StatusLine, StatusWatch, status_text
from legws_daemon.transport.session import keys
from tests.daemon.procs import LEGWS, REPO, env, write_profile
from tests.net import free_port
from tests.reliability.escape_corpus import hostile_texts, unsafe_in

ROBOT = "sawyer_sim"
#: The hostile names a status can carry (a label is at most 64 characters).
NAMES = [(label, text) for label, text in hostile_texts("g") if len(text) <= 64]


def hostile_status(seq: int, decision: int, name: str) -> dict[str, Any]:
    """A valid status (teleop, an EE pose, two targets) with ``name`` in every name."""
    other = f"{name[:60]}_alt"
    return {
        "schema": 1, "robot": ROBOT, "seq": seq, "stamp": time.time(), "mode": "teleop",
        "adapter": "sim", "stage": name, "decision": decision,
        "posterior": {name: 0.7, other: 0.3}, "committed": name, "phase": name,
        "fault": f"fault {name}",
        "operator": {"source": name, "session": "not-this-one"},
        "ee": {"position": [0.55, 0.0, 0.25], "quaternion": [1.0, 0.0, 0.0, 0.0]},
        "targets": {name: [0.6, 0.1, 0.1], other: [0.6, -0.1, 0.1]},
    }  # fmt: skip


def daemon_config(port: int) -> zenoh.Config:
    """The fake daemon's session: a peer listening on one loopback port, no scouting."""
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps("peer"))
    cfg.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    cfg.insert_json5("connect/endpoints", "[]")
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("scouting/gossip/enabled", "false")
    return cfg


@contextmanager
def hostile_daemon(port: int) -> Iterator[threading.Event]:
    """Publish statuses at 10 Hz: a plain one until a publisher steers (its joystick
    messages arrive), then each hostile name for three statuses, then ``idle`` (the task is
    done: the sim-user stops). Yields the event set when the idle statuses start."""
    k = keys(ROBOT)
    steering, finished, stop = threading.Event(), threading.Event(), threading.Event()
    with zenoh.open(daemon_config(port)) as session:
        sub = session.declare_subscriber(k["joystick"], lambda _sample: steering.set())

        def publish() -> None:
            seq = i = 0
            while not stop.wait(0.1):
                seq += 1
                if finished.is_set():
                    body: dict[str, Any] = {**hostile_status(seq, 0, "done"), "mode": "idle"}
                elif not steering.is_set():
                    body = hostile_status(seq, 1, "pick")  # a plain one until it steers
                else:
                    body = hostile_status(seq, i // 3 + 2, NAMES[i // 3][1])
                    i += 1
                    if i >= 3 * len(NAMES):
                        finished.set()
                session.put(k["status"], json.dumps(body).encode())

        thread = threading.Thread(target=publish, daemon=True)
        thread.start()
        try:
            yield finished
        finally:
            stop.set()
            thread.join(2.0)
            sub.undeclare()  # type: ignore[no-untyped-call]


def accepted(name: str) -> bool:
    """Whether a publisher takes the hostile status with ``name`` (parses and validates)."""
    payload = json.dumps(hostile_status(1, 2, name)).encode()
    try:
        parse(StatusMessage, payload, keys(ROBOT)["status"])
    except InputError:
        return False
    return True


def test_the_status_text_of_a_hostile_status_is_safe() -> None:
    for label, name in NAMES:
        try:
            status = StatusMessage.model_validate(hostile_status(1, 1, name))
        except ValueError:
            continue  # (a lone surrogate is no valid status text)
        line = status_text(status, session="mine")
        assert not unsafe_in(line), (label, line)
        assert "(not you)" in line and " · deadman off" in line


@pytest.mark.slow  # ~5 s: a publisher through 15 hostile names
def test_a_sim_user_against_a_hostile_daemon_prints_nothing_unsafe(tmp_path: Path) -> None:
    port = free_port()
    profile = write_profile(tmp_path, "sim", port)
    t0 = time.monotonic()
    with hostile_daemon(port) as finished:
        done = subprocess.run(
            [*LEGWS, "joystick", "sim-user", "--profile", str(profile), "--duration", "40",
             "--wait-daemon", "20"],
            cwd=REPO, capture_output=True, timeout=90, check=False, env=env(),
        )  # fmt: skip
        assert finished.is_set(), done.stderr.decode(errors="replace")[-2000:]
    seconds = time.monotonic() - t0
    out = done.stdout.decode()  # strict: no byte that is not UTF-8
    err = done.stderr.decode()
    assert done.returncode == 0, err[-2000:]
    assert unsafe_in(out) == [] and unsafe_in(err) == [], err[-2000:]
    assert "\x1b" not in out + err
    shown = [line for line in err.splitlines() if line.startswith("legws: daemon: teleop")]
    # every hostile status the publisher takes (a status refused on receipt is not shown)
    # is shown, a line per change, each name with its hostile characters as escapes
    taken = [name for _, name in NAMES if accepted(name)]
    for name in taken:
        stage = f"stage {safe_text(name, NAME_LIMIT)} · "
        assert any(stage in line and "(not you)" in line for line in shown), (stage, shown)
    if taken:
        assert any("\\u" in line or "\\x" in line for line in shown), shown
        assert "the user went for g\\" in err  # its summary of the goals it went for
    assert seconds < 60


class _Given(StatusWatch):
    """A watch whose newest status is the one given (whatever a parser would refuse)."""

    def __init__(self, status: StatusMessage) -> None:
        super().__init__(keys(ROBOT)["status"])
        self.given = status

    @property
    def newest(self) -> StatusMessage | None:
        return self.given


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_the_status_line_writes_every_hostile_name_safely_to_a_pipe_and_a_terminal() -> None:
    for label, name in NAMES:
        try:
            status = StatusMessage.model_validate(hostile_status(1, 2, name))
        except ValueError:
            continue
        pipe, terminal = io.StringIO(), _Terminal()
        StatusLine(_Given(status), pipe, "mine", "legws: daemon: ").show()
        StatusLine(_Given(status), terminal, "mine", "legws: daemon: ").show()
        assert pipe.getvalue().endswith("\n") and unsafe_in(pipe.getvalue()) == [], label
        drawn = terminal.getvalue()  # the line between its own return and erase-to-the-end
        assert drawn.startswith("\r") and drawn.endswith("\x1b[K"), label
        assert unsafe_in(drawn[1:-3]) == [], (label, drawn)


def test_zenoh_logs_nothing_of_its_own_whatever_rust_log_says(tmp_path: Path) -> None:
    # legws never starts zenoh's Rust log (it would write coloured lines to stdout); a
    # connect that fails again and again is silent but for legws's own one line
    port = free_port()  # nobody listens here
    profile = write_profile(tmp_path, "sim", port)
    done = subprocess.run(
        [*LEGWS, "joystick", "sim-user", "--profile", str(profile), "--wait-daemon", "1"],
        cwd=REPO, capture_output=True, text=True, timeout=60, check=False,
        env={**env(), "RUST_LOG": "trace"},
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert done.stdout == ""
    assert [line.split(":")[0:2] for line in done.stderr.splitlines()] == [["legws", " error"]]


@pytest.mark.slow  # ~15 s of real time (rerun's own wait at shutdown), 2 s of CPU
@pytest.mark.parametrize("no_color", [None, ""])  # legws's default; a user's empty one
def test_rerun_lines_reach_the_terminal_safe_and_uncoloured(no_color: str | None) -> None:
    # rerun writes its own lines from Rust (here: a viewer it cannot reach), coloured even
    # through a pipe: NO_COLOR before it loads, and the lines of the close caught and
    # passed on safe, colours dropped
    viewer = free_port()  # nobody listens there
    script = (
        "from legws_daemon.telemetry.rerun_log import RerunLog\n"
        f"log = RerunLog('connect:rerun+http://127.0.0.1:{viewer}/proxy', robot='r')\n"
        "log.close()\n"
    )
    run_env = {k: v for k, v in env().items() if k != "NO_COLOR"}
    if no_color is not None:
        run_env["NO_COLOR"] = no_color
    done = subprocess.run(
        [sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True,
        timeout=60, check=False, env=run_env,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"127.0.0.1:{viewer}" in done.stderr  # rerun's own lines came...
    assert unsafe_in(done.stdout + done.stderr) == [], done.stderr[-2000:]  # ...safe
    assert "\\x1b" not in done.stderr  # and without their colours

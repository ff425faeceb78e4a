"""Start-up with the bridge already running: the daemon finds it every time.

The fake bridge (``legws bridge fake``) runs first and dials the daemon's port, where
nobody listens yet: zenoh retries with a growing back-off. Before the fix the back-off
(up to 4 s) outgrew the daemon's ``bridge_timeout`` (3 s), and 2 starts in 7 failed — or,
with ``fallback_to_sim = true`` as here, started the stand-in while the real arm was up.
Now the profile transport's retry period is capped (:data:`~legws_daemon.transport.session.
RETRY_MAX_MS`), and a silent bridge is told apart from an absent one.
"""

from __future__ import annotations

import subprocess
import threading
import time
from pathlib import Path

import pytest

from legws_daemon.formats.bridge_messages import bridge_keys
from legws_daemon.formats.profile import ProfileSpec, load_profile
from legws_daemon.transport.session import config_from_spec, open_session
from tests.daemon.procs import LEGWS, env, start, stop, write_profile
from tests.net import free_port

#: What decides a start: how long the bridge has dialled in vain when the daemon's session
#: opens. zenoh's retry period doubles from 0.1 s (dials at 0.1, 0.3, 0.7, 1.5, 3.1, 6.3 s
#: after it lost its peer); capped at 4 s as it was before the fix, the next dial after
#: 6.3 s comes at 10.3 s: a session opened 6.5 or 7 s after the bridge lost the daemon
#: hears nothing for over 3 s (``bridge_timeout``), and one opened at 10.5 s neither with a
#: cap of 8 s. The waits, s, of the sessions opened the daemon's way (the profile's
#: transport, in this process: ~0 CPU) ...
WAITS = (2.0, 3.2, 6.5, 7.0, 10.5, 1.0)
#: ... and of whole daemon starts (adapter, fallback decision and all, ~3 s of CPU each;
#: its session opens ~2 s after the wait, the import and the model built).
START_WAITS = (5.0, 0.5)


def _daemon(profile: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*LEGWS, "daemon", "--profile", str(profile), "--scene", "desk", "--duration", "0.3",
         "--allow-motion", "--insecure-transport"],
        capture_output=True, text=True, timeout=60, check=False, env=env(),
    )  # fmt: skip


def _hears_the_bridge(spec: ProfileSpec) -> float | None:
    """Seconds from opening a session until the bridge's first state, or ``None`` when
    none came within the profile's ``bridge_timeout`` (the daemon would have given up)."""
    heard = threading.Event()
    with open_session(config_from_spec(spec.transport)) as session:
        t0 = time.monotonic()
        sub = session.declare_subscriber(bridge_keys(spec.robot)["state"], lambda _: heard.set())
        try:
            ok = heard.wait(spec.link.bridge_timeout)
        finally:
            sub.undeclare()  # type: ignore[no-untyped-call]
        return time.monotonic() - t0 if ok else None


@pytest.mark.slow
def test_the_daemon_finds_a_running_bridge_every_time(tmp_path: Path) -> None:
    profile = write_profile(
        tmp_path, "sawyer", free_port(), {"fallback_to_sim = false": "fallback_to_sim = true"}
    )
    spec = load_profile(profile)
    bridge = start(["bridge", "fake", "--profile", str(profile)], tmp_path / "bridge.log")
    heard: list[float | None] = []
    outcomes: list[str] = []
    try:
        for wait in WAITS:
            time.sleep(wait)
            heard.append(_hears_the_bridge(spec))
        for wait in START_WAITS:
            time.sleep(wait)
            run = _daemon(profile)
            assert run.returncode == 0, run.stderr[-2000:]
            fell_back = "adapter=sim" in run.stderr
            outcomes.append("sim" if fell_back else "sawyer")
            assert "started adapter=sawyer" in run.stderr or fell_back, run.stderr[-2000:]
    finally:
        stop(bridge)
    assert None not in heard, list(zip(WAITS, heard, strict=True))
    assert outcomes == ["sawyer"] * len(START_WAITS), outcomes

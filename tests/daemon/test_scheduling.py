"""Real-time scheduling of the control loop: granted where permitted, refused in one line
elsewhere, inherited by the threads the loop starts, and reported in status."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from legws_daemon.daemon.scheduling import current_priority, enter_realtime
from tests.daemon.procs import monitor, ready, start, stop, write_profile
from tests.net import free_port

linux = pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="Linux only")


def _in_thread(fn: object) -> dict[str, object]:
    """Run ``fn`` in a fresh thread (the test's own thread keeps its scheduling)."""
    out: dict[str, object] = {}

    def run() -> None:
        out.update(fn())  # type: ignore[operator]

    t = threading.Thread(target=run)
    t.start()
    t.join(10.0)
    return out


@linux
def test_granted_where_permitted_and_inherited_by_new_threads() -> None:
    def probe() -> dict[str, object]:
        problem = enter_realtime(20)
        child: dict[str, int] = {}
        t = threading.Thread(target=lambda: child.update(p=current_priority()))
        t.start()
        t.join(5.0)
        return {"problem": problem, "priority": current_priority(), "child": child["p"]}

    out = _in_thread(probe)
    if out["problem"] is None:
        assert (out["priority"], out["child"]) == (20, 20)
    else:  # not root and no rtprio limit: refused, nothing changed
        assert "not permitted" in str(out["problem"])
        assert out["priority"] == 0


@linux
def test_refused_without_the_privilege_in_one_line() -> None:
    """As an unprivileged user (root drops to nobody in a child process)."""
    code = (
        "import os, resource\n"
        "from legws_daemon.daemon.scheduling import enter_realtime, current_priority\n"
        "resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))\n"
        "if os.geteuid() == 0: os.setgid(65534); os.setuid(65534)\n"
        "print(repr(enter_realtime(50)), current_priority())\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False
    )
    assert run.returncode == 0, run.stderr
    message, priority = run.stdout.rsplit(" ", 1)
    assert "not permitted to use SCHED_FIFO priority 50" in message
    assert "RLIMIT_RTPRIO" in message and "\\n" not in message
    assert int(priority) == 0


@pytest.mark.parametrize("priority", [0, 100, -1])
def test_out_of_range_is_refused(priority: int) -> None:
    assert "not in 1..99" in (enter_realtime(priority) or "")


@linux
@pytest.mark.slow
def test_the_daemon_reports_its_loop_priority(tmp_path: Path) -> None:
    port = free_port()
    profile = write_profile(
        tmp_path, "sim", port, {"realtime_priority = 0": "realtime_priority = 20"}
    )
    daemon = start(["daemon", "--profile", str(profile), "--duration", "30"], tmp_path / "d.log")
    try:
        with monitor(port, "sawyer_sim") as m:
            assert m.wait_for(ready, 30), (tmp_path / "d.log").read_text()
            granted = m.latest()["realtime_priority"]  # type: ignore[index]
            warned = [e for e in m.events if "realtime" in e["detail"]]
    finally:
        code, _ = stop(daemon)
    assert code == 0
    log = (tmp_path / "d.log").read_text()
    if granted == 20:
        assert "realtime=" not in log
    else:  # refused: normal scheduling, said once
        assert granted == 0 and ("not permitted" in log or warned)

"""Run many ``legws`` command lines fast: one process imports legws once, then forks a
child per case, as a real ``legws`` process would run it (its own cwd, environment, file
descriptors 1 and 2, exit code). For each case it measures the wall time and the child's
peak resident set (``wait4``'s ``ru_maxrss``), and kills a child that runs over its time.

Usage: ``python -m tests.reliability.corpus_runner CASES.json RESULTS.json``, where CASES
is a list of ``{"argv": [...], "cwd": str, "env": {...}}`` and RESULTS gets, per case,
``{"code", "stdout", "stderr", "seconds", "maxrss_mib", "killed"}``.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
import time
from pathlib import Path
from typing import Any

#: Seconds a case may run before it is killed: the issue's bound, 5 s, unless
#: ``LEGWS_CASE_TIME_LIMIT`` says otherwise (the suite gives a loaded machine more).
TIME_LIMIT = float(os.environ.get("LEGWS_CASE_TIME_LIMIT", "5.0"))


def _preload() -> None:
    """Import what the commands import lazily, so that a forked case pays nothing for it.
    Nothing here starts a thread or opens a session (fork copies no busy lock)."""
    import legws_daemon.cli.main
    import legws_daemon.daemon.service
    import legws_daemon.design.optimize
    import legws_daemon.design.stage_plan
    import legws_daemon.robot.render
    import legws_daemon.sim.evaluate
    import legws_daemon.task.diagram
    import legws_daemon.telemetry.recording
    import legws_daemon.telemetry.rerun_log  # noqa: F401


def _child(case: dict[str, Any], out: str, err: str) -> None:
    from legws_daemon.cli.main import run

    os.setsid()  # a killed case takes its own children with it
    os.chdir(case["cwd"])
    os.environ.update(case.get("env", {}))
    for fd, name in ((1, out), (2, err)):
        f = os.open(name, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        os.dup2(f, fd)
        os.close(f)
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    code = 1
    try:
        code = run(case["argv"])
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    except BaseException:
        import traceback

        traceback.print_exc()
        code = 1
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def run_case(case: dict[str, Any], scratch: Path) -> dict[str, Any]:
    out, err = scratch / "stdout", scratch / "stderr"
    t0 = time.monotonic()
    pid = os.fork()
    if pid == 0:
        _child(case, str(out), str(err))
    killed = False
    while True:
        done, status, usage = os.wait4(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() - t0 > TIME_LIMIT:
            killed = True
            for target in (-pid, pid):  # its process group, and itself
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.kill(target, signal.SIGKILL)
            done, status, usage = os.wait4(pid, 0)
            break
        time.sleep(0.005)
    seconds = time.monotonic() - t0
    code = os.waitstatus_to_exitcode(status)
    return {
        "code": code,
        "stdout": out.read_text(errors="replace"),
        "stderr": err.read_text(errors="replace"),
        "seconds": seconds,
        "maxrss_mib": usage.ru_maxrss / 1024,  # KiB on Linux
        "killed": killed,
    }


def main() -> None:
    cases = json.loads(Path(sys.argv[1]).read_text())
    scratch = Path(sys.argv[2]).parent / ".runner"
    scratch.mkdir(exist_ok=True)
    _preload()
    results = [run_case(case, scratch) for case in cases]
    Path(sys.argv[2]).write_text(json.dumps(results))


if __name__ == "__main__":
    main()

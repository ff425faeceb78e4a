"""Real-time scheduling for the control loop's thread (Linux ``SCHED_FIFO``).

On a shared machine the loop competes for the CPU with everything else: the daemon's own
zenoh and load threads, a command flood's client, a compiler. At normal priority a 2-ms
tick then takes 5-8 ms at p99 under a burst of commands on two cores; with ``SCHED_FIFO``
it preempts them and stays at ~3 ms (``docs/benchmarks.md``). This is what ros2_control
does for its loop.

The priority comes from the profile (``control.realtime_priority``; 0: normal scheduling).
Getting it needs ``CAP_SYS_NICE`` or an ``RLIMIT_RTPRIO`` at least that high (``ulimit -r``,
``/etc/security/limits.conf``: ``@legws - rtprio 60``, or systemd ``LimitRTPRIO=60``); when
refused the daemon runs at normal priority and says so. Linux limits real-time threads to
95 % of each second (``kernel.sched_rt_runtime_us``), so a loop gone wrong cannot lock the
machine up.

A thread inherits its creator's policy, and the load preparer (started by the loop's thread)
keeps the loop's priority on purpose. It holds the interpreter lock the loop needs: at
normal priority any busy thread preempts it while it holds the lock and the loop waits
(priority inversion). Measured in the command flood (3 runs each): preparer at normal
priority, tick p99 3.4-11.6 ms; one real-time priority below the loop, 5.4-6.3 ms; at the
loop's priority, 3.6-4.2 ms. The loop gate (:mod:`.gate`) keeps it off the interpreter
while a tick runs, and on two or more cores the kernel runs the two on different cores.
"""

from __future__ import annotations

import os


def enter_realtime(priority: int) -> str | None:
    """Put the calling thread on ``SCHED_FIFO`` at ``priority`` (1-99); returns ``None``
    when granted, else why not (one line)."""
    if not 1 <= priority <= 99:
        return f"priority {priority} is not in 1..99"
    if not hasattr(os, "sched_setscheduler"):
        return "this system has no SCHED_FIFO (Linux only)"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        return (
            f"not permitted to use SCHED_FIFO priority {priority}: run with CAP_SYS_NICE or "
            f"an RLIMIT_RTPRIO of at least {priority} (ulimit -r, limits.conf, LimitRTPRIO=)"
        )
    except OSError as err:
        return f"SCHED_FIFO priority {priority} refused: {err.strerror or err}"
    return None


def current_priority() -> int:
    """The calling thread's ``SCHED_FIFO``/``SCHED_RR`` priority, 0 when it is not real-time."""
    if not hasattr(os, "sched_getscheduler"):
        return 0
    policy = os.sched_getscheduler(0)
    if policy not in (os.SCHED_FIFO, os.SCHED_RR):
        return 0
    return int(os.sched_getparam(0).sched_priority)

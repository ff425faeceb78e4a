"""Process pools that are safe in a process with threads.

By the time a pool starts, this process may run threads of zenoh, Rerun or numba; ``fork``
copies their locks mid-use and a child can hang for ever on one (seen in the test suite).
Workers therefore start from a fresh *forkserver* process instead (Python 3.14's default on
Linux): they import what they need and share no lock with this process.
"""

from __future__ import annotations

import multiprocessing
from multiprocessing.context import BaseContext


def worker_context() -> BaseContext:
    """The multiprocessing context of every legws process pool."""
    return multiprocessing.get_context("forkserver")

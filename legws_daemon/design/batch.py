"""Many optimisation runs (scenes × seeds) on an existing engine: a local process pool by
default, a Dask distributed cluster when given its scheduler address.

Both go through the ``concurrent.futures.Executor`` interface (Dask's
``Client.get_executor()``), so there is one code path and no home-made scheduler. Dask is an
optional extra (``pip install 'legws[dask]'``); workers need legws installed and the Sawyer
assets fetched (``legws assets fetch``).
"""

from __future__ import annotations

import os
import re
import socket
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from legws_daemon.errors import InputError, LegwsError
from legws_daemon.formats.operator_file import OperatorFile
from legws_daemon.robot.assets import arm_dir
from legws_daemon.workers import worker_context

#: A Dask scheduler address as ``--dask`` takes it.
DASK_ADDRESS = re.compile(r"(tcp|tls|inproc|ucx)://[^\s/]+(:\d{1,5})?")
#: Seconds to reach the scheduler: a live one answers in well under a second.
DASK_CONNECT_TIMEOUT = 3


@dataclass(frozen=True, slots=True)
class Job:
    scene: str  # scene name or path, resolved on the worker
    seed: int
    out_dir: str
    method: str
    iterations: int
    movable: tuple[str, ...] | None
    objective: str = "slack"
    commit_form: str = "sum"
    operators: tuple[OperatorFile, ...] = ()  # design for these people (the worst of them)


def run_job(job: Job) -> dict[str, Any]:
    """One optimisation run (executed on a worker process)."""
    from legws_daemon.design.optimize import optimize
    from legws_daemon.scene.catalog import load_scene

    summary = optimize(
        load_scene(job.scene),
        Path(job.out_dir),
        method=job.method,
        iterations=job.iterations,
        seed=job.seed,
        movable=job.movable,
        objective=job.objective,
        commit_form=job.commit_form,
        operators=job.operators,
    )
    return {**summary, "seed": job.seed, "out": job.out_dir}


@contextmanager
def executor(dask: str | None, workers: int) -> Iterator[Executor]:
    """A process pool, or the executor of the Dask cluster at ``dask`` (``tcp://host:port``)."""
    if dask is None:
        with ProcessPoolExecutor(max_workers=workers, mp_context=worker_context()) as pool:
            yield pool
        return
    if not DASK_ADDRESS.fullmatch(dask):
        raise InputError(f"expected tcp://HOST:PORT, got {dask!r}", field="--dask")
    _probe_scheduler(dask)
    try:
        from distributed import Client
    except ImportError:
        raise InputError(
            "--dask needs the optional extra: pip install 'legws[dask]'", field="--dask"
        ) from None
    try:
        client = Client(  # type: ignore[no-untyped-call]
            dask, timeout=DASK_CONNECT_TIMEOUT, set_as_default=False
        )
    except (OSError, TimeoutError) as err:
        raise InputError(
            f"cannot reach the Dask scheduler at {dask}: {err}", field="--dask"
        ) from None
    try:
        yield client.get_executor(pure=False)  # type: ignore[no-untyped-call]
    finally:
        client.close()  # type: ignore[no-untyped-call]


def _probe_scheduler(address: str) -> None:
    """One TCP connection to a ``tcp://`` scheduler first: nobody there (refused, no route)
    is one line at once, before Dask is imported or anything is printed."""
    scheme, _, rest = address.partition("://")
    host, _, port = rest.rpartition(":")
    if scheme != "tcp" or not port.isdigit():
        return
    if not 1 <= int(port) <= 65535:
        raise InputError(f"port {port} is not in 1-65535", field="--dask")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), DASK_CONNECT_TIMEOUT):
            pass
    except OSError as err:
        raise InputError(
            f"cannot reach the Dask scheduler at {address}: {err.strerror or err}", field="--dask"
        ) from None


def run_all(
    jobs: Sequence[Job],
    *,
    dask: str | None = None,
    workers: int = min(2, os.cpu_count() or 1),
    progress: Callable[[dict[str, Any]], object] | None = None,
    started: Callable[[], object] | None = None,
) -> list[dict[str, Any]]:
    """Run every job; results in the order of ``jobs``.

    ``started`` is called once the pool or the cluster is there (a progress bar appears
    only then: a scheduler that cannot be reached is one error line, nothing before it).
    """
    results: dict[int, dict[str, Any]] = {}
    if dask is None:
        arm_dir()  # a missing or damaged robot model: one line here, not in each worker
    with executor(dask, workers) as pool:
        if started is not None:
            started()
        futures = {pool.submit(run_job, job): i for i, job in enumerate(jobs)}
        for fut in as_completed(futures):
            try:
                results[futures[fut]] = fut.result()
            except LegwsError as err:
                job = jobs[futures[fut]]
                raise LegwsError(f"{job.scene} seed {job.seed}: {err}") from None
            if progress is not None:
                progress(results[futures[fut]])
    return [results[i] for i in range(len(jobs))]

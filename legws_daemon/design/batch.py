"""Many optimisation runs (scenes × seeds) on an existing engine: a local process pool by
default, a Dask distributed cluster when given its scheduler address.

Both go through the ``concurrent.futures.Executor`` interface (Dask's
``Client.get_executor()``), so there is one code path and no home-made scheduler. Dask is an
optional extra (``pip install 'legws[dask]'``); workers need legws installed and the Sawyer
assets fetched (``legws assets fetch``).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from legws_daemon.errors import InputError, LegwsError
from legws_daemon.workers import worker_context


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
    )
    return {**summary, "seed": job.seed, "out": job.out_dir}


@contextmanager
def executor(dask: str | None, workers: int) -> Iterator[Executor]:
    """A process pool, or the executor of the Dask cluster at ``dask`` (``tcp://host:port``)."""
    if dask is None:
        with ProcessPoolExecutor(max_workers=workers, mp_context=worker_context()) as pool:
            yield pool
        return
    try:
        from distributed import Client
    except ImportError:
        raise InputError(
            "--dask needs the optional extra: pip install 'legws[dask]'", field="--dask"
        ) from None
    try:
        client = Client(dask, timeout=10, set_as_default=False)  # type: ignore[no-untyped-call]
    except (OSError, TimeoutError) as err:
        raise InputError(
            f"cannot reach the Dask scheduler at {dask}: {err}", field="--dask"
        ) from None
    try:
        yield client.get_executor(pure=False)  # type: ignore[no-untyped-call]
    finally:
        client.close()  # type: ignore[no-untyped-call]


def run_all(
    jobs: Sequence[Job],
    *,
    dask: str | None = None,
    workers: int = min(2, os.cpu_count() or 1),
    progress: Callable[[dict[str, Any]], object] | None = None,
) -> list[dict[str, Any]]:
    """Run every job; results in the order of ``jobs``."""
    results: dict[int, dict[str, Any]] = {}
    with executor(dask, workers) as pool:
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

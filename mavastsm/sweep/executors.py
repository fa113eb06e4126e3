"""Where the sweep's units of work run: ``concurrent.futures`` executors, nothing home-made.

* local (default): ``ProcessPoolExecutor`` (spawn) with one worker per core;
* ``--dask-local N``: a Dask ``LocalCluster`` (scheduler + N worker processes) and its client's executor;
* ``--scheduler tcp://HOST:PORT``: an existing Dask scheduler (workers need mavastsm installed).

Dask is the optional extra ``mavastsm[cluster]``. A unit of work is a pure function of (spec, rows), so the table
is the same whatever executor runs it.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
from concurrent.futures import Executor, ProcessPoolExecutor

from ..errors import ConfigError

SCHEDULER_TIMEOUT_S = 5.0


def _dask():
    try:
        import distributed
    except ImportError:
        raise ConfigError("Dask is not installed: pip install \"mavastsm[cluster]\"") from None
    return distributed


@contextlib.contextmanager
def make_executor(workers: int | None = None, scheduler: str | None = None, dask_local: int | None = None):
    """Yield (executor, description). ConfigError (one line) when the scheduler cannot be reached."""
    if scheduler and dask_local:
        raise ConfigError("--scheduler and --dask-local: choose one")
    if scheduler or dask_local:
        distributed = _dask()
        cluster = None
        try:
            if dask_local:
                cluster = distributed.LocalCluster(n_workers=int(dask_local), threads_per_worker=1, processes=True,
                                                   dashboard_address=None, silence_logs=50)
                client = distributed.Client(cluster)
                where = f"Dask LocalCluster, {dask_local} worker processes"
            else:
                try:
                    client = distributed.Client(scheduler, timeout=SCHEDULER_TIMEOUT_S)
                except (OSError, TimeoutError, ValueError) as exc:
                    raise ConfigError(f"--scheduler {scheduler}: unreachable ({type(exc).__name__}: {exc})".splitlines()[0]) from None
                where = f"Dask scheduler {scheduler}"
            try:
                yield client.get_executor(pure=False), where
            finally:
                client.close()
        finally:
            if cluster is not None:
                cluster.close()
        return
    n = workers or os.cpu_count() or 1
    pool: Executor = ProcessPoolExecutor(max_workers=n, mp_context=mp.get_context("spawn"))
    try:
        yield pool, f"local processes ({n})"
    finally:
        pool.shutdown(wait=True, cancel_futures=True)

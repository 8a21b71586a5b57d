"""Where runs execute: in this process, in worker processes we can kill, on Dask.

:func:`execute_all` picks the executor. In-process runs are the fastest and
accept a registry built by hand; worker processes isolate the sweep from what
a run can do to its process (``os._exit``, a segfault, a hang in compiled code
that no signal interrupts). One concept a module:

========== ===============================================================
``start``  how workers start (fork or spawn, :func:`start_method`), one
           BLAS thread each
``worker`` one worker process, its loop, the session of a thread, the
           workers started ahead (:func:`started`)
``pool``   the pool of workers: replacement, retries, deadlines, which
           queued run a free worker takes
``dask``   a sweep on a Dask cluster (:func:`execute_on_dask`)
========== ===============================================================

The names other modules use are re-exported here.
"""

from __future__ import annotations

from collections.abc import Callable, Generator

from idbench.plan.runspec import RunSpec
from idbench.run.executors.dask import (
    ClusterLost,
    connect,
    execute_on_dask,
    quiet_logging,
)
from idbench.run.executors.pool import (
    GRACE_S,
    LOOKAHEAD,
    MAX_ATTEMPTS,
    TICK_S,
    Pool,
    execute_on_workers,
    next_run_index,
)
from idbench.run.executors.start import (
    START_METHOD_ENV,
    THREAD_ENV,
    one_blas_thread,
    single_thread_env,
    start_method,
)
from idbench.run.executors.worker import (
    STOP_GRACE_S,
    RunResult,
    Worker,
    run_in_worker,
    started,
    started_ahead,
    worker_lost,
    worker_session,
)
from idbench.run.harness import execute
from idbench.run.session import Session

__all__ = [
    "GRACE_S",
    "LOOKAHEAD",
    "MAX_ATTEMPTS",
    "START_METHOD_ENV",
    "STOP_GRACE_S",
    "THREAD_ENV",
    "TICK_S",
    "ClusterLost",
    "Pool",
    "RunResult",
    "Worker",
    "connect",
    "execute",
    "execute_all",
    "execute_on_dask",
    "execute_on_workers",
    "next_run_index",
    "one_blas_thread",
    "quiet_logging",
    "run_in_worker",
    "single_thread_env",
    "started_ahead",
    "start_method",
    "started",
    "worker_lost",
    "worker_session",
]


def execute_all(
    runs: list[RunSpec],
    session: Session,
    *,
    jobs: int = 1,
    timeout: float | None = None,
    tick: Callable[[], None] | None = None,
) -> Generator[RunResult, None, None]:
    """Execute ``runs`` and yield each result as it finishes.

    Parameters
    ----------
    runs
        What to run, in the order to start them.
    session
        This process's session: in-process runs use it; forked workers start
        with a copy of it, spawned ones with what it has to share
        (:meth:`Session.shared`); workers pass on to each other what they
        compute, so a reference fit or direct run is done again only by a
        worker that needs it while another is computing it.
    jobs
        Worker processes; 1 without a timeout runs in this process.
    timeout
        With a timeout, runs always go to worker processes (even ``jobs=1``)
        so that a run hung in compiled code can be killed.
    tick
        Called at least every ``TICK_S`` seconds while worker processes run,
        and whenever one has news (a progress display without a thread of its
        own redraws its clock). If it raises, it is not called again.
    """
    if jobs == 1 and timeout is None:
        with one_blas_thread():
            for spec in runs:
                yield execute(spec, session)
    else:
        yield from execute_on_workers(runs, jobs, timeout, session, tick)

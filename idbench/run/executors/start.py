"""How worker processes start: forked or spawned, with one BLAS thread each.

On Linux, when this process runs one Python thread, workers are forked from
it once it has planned the sweep, so they begin with its imports, its built
models and its probed truths (nothing to import or build again: 2 jobs
1.81-1.84x faster than 1 on the default compare, 1.69x spawned,
``benchmarks/sweep.py``); otherwise, or with ``IDBENCH_START_METHOD=spawn``,
they are spawned, as fresh interpreters that import idbench and the plugins,
and start ahead of planning (:func:`idbench.run.executors.worker.started`).
Either way BLAS and OpenMP libraries use one thread in a worker.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal
import sys
import threading
from collections.abc import Iterator
from typing import Any

from idbench.plan.config import ConfigError

THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
START_METHOD_ENV = "IDBENCH_START_METHOD"
"""``fork``, ``spawn`` or ``auto`` (the default): see :func:`start_method`."""


def one_blas_thread() -> Any:
    """A context in which BLAS/OpenMP libraries use one thread.

    Runs are many small dense and sparse solves: threaded BLAS only adds
    overhead (10x slower on a loaded 2-core machine for the full UKF's
    eigendecompositions), and parallelism comes from running runs side by side.
    """
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1)


def single_thread_env() -> dict[str, str]:
    """Environment that pins BLAS/MKL/OpenMP to one thread per worker."""
    return {k: "1" for k in THREAD_ENV}


@contextlib.contextmanager
def single_thread_environ() -> Iterator[None]:
    """Set :func:`single_thread_env` for the block (workers inherit it)."""
    saved = {k: os.environ.get(k) for k in THREAD_ENV}
    os.environ.update(single_thread_env())
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextlib.contextmanager
def sigint_ignored() -> Iterator[None]:
    """Ignore SIGINT in the block (main thread only; elsewhere: unchanged).

    A process started here begins with SIGINT ignored, so a Ctrl-C during its
    imports does not print its traceback; the parent handles Ctrl-C.
    """
    try:
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:  # None: set outside Python; the default is the closest
        signal.signal(signal.SIGINT, signal.SIG_DFL if old is None else old)


def start_method() -> str:
    """How worker processes start: ``"fork"`` or ``"spawn"``.

    ``IDBENCH_START_METHOD`` chooses; ``auto`` (or unset) forks on Linux when
    this process runs one Python thread, and spawns otherwise: a fork copies
    a lock another thread may hold at that moment, which the worker could
    then wait on forever (a progress bar's refresh thread, a notebook's
    kernel threads). Decided again for each worker started, so a thread
    started during a sweep makes its replacement workers spawned. Threads of
    compiled libraries (BLAS and OpenMP pools, Arrow's) are not counted:
    they re-initialise in a forked child, or are limited to one thread there
    (:func:`idbench.run.executors.worker._forked`). macOS forks unsafely (system
    frameworks), Windows not at all: ``fork`` is refused where the platform
    has no fork.

    Raises
    ------
    ConfigError
        If ``IDBENCH_START_METHOD`` is none of ``auto``, ``fork``, ``spawn``.
    """
    choice = os.environ.get(START_METHOD_ENV, "").strip().lower() or "auto"
    if choice not in ("auto", "fork", "spawn"):
        raise ConfigError(
            f"{START_METHOD_ENV}={choice!r}: allowed are auto, fork, spawn"
        )
    if choice == "fork" and "fork" not in mp.get_all_start_methods():
        raise ConfigError(
            f"{START_METHOD_ENV}=fork: this platform cannot fork; "
            "allowed are auto, spawn"
        )
    if choice == "auto":
        alone = threading.active_count() == 1
        choice = "fork" if alone and sys.platform.startswith("linux") else "spawn"
    return choice


FORK_WARNING = r".*multi-threaded, use of fork\(\) may lead to deadlocks"
"""Python 3.12+ warns of a fork while compiled libraries run threads of their
own (BLAS pools): those are fork-safe, and Python threads were checked."""

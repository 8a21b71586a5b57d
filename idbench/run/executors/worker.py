"""A worker process: one run at a time, killable, dying with its parent.

A worker runs one run at a time, so a worker that dies is charged to exactly
the run it was running, never to a sibling. Workers die with the parent
process (Linux: ``PR_SET_PDEATHSIG``; elsewhere a watchdog thread notices the
parent has gone). A forked worker drops what belongs to the parent's terminal
(its log handlers, a progress bar's hold on stdout/stderr) and limits BLAS to
one thread, as a spawned one does (:mod:`idbench.run.executors.start`).
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing as mp
import os
import signal
import sys
import threading
import time
import warnings
from collections.abc import Iterator
from multiprocessing.connection import Connection
from typing import Any

from idbench.plan.runspec import RunSpec
from idbench.run.executors.start import (
    FORK_WARNING,
    sigint_ignored,
    single_thread_environ,
    start_method,
)
from idbench.run.harness import execute
from idbench.run.rows import base_row, empty_parameter_columns
from idbench.run.session import Session

log = logging.getLogger(__name__)

RunResult = tuple[dict[str, Any], list[dict[str, Any]]]
STOP_GRACE_S = 0.05
"""Seconds an idle worker asked to stop gets before it is killed."""

_LOCAL = threading.local()


def worker_session() -> Session:
    """The session of the calling thread (built on first use).

    One per thread, never shared: a session holds models with cached
    factorizations, which two threads must not use at once (a Dask worker
    runs several tasks in threads).
    """
    session: Session | None = getattr(_LOCAL, "session", None)
    if session is None:
        session = _LOCAL.session = Session()
    return session


def run_in_worker(spec: RunSpec) -> RunResult:
    """Execute ``spec`` with this thread's session (a Dask task).

    BLAS threads are the worker's (start it with ``OMP_NUM_THREADS=1``): a
    process-wide limit set here would race between the worker's threads.
    """
    return execute(spec, worker_session())


def worker_lost(spec: RunSpec, why: str) -> RunResult:
    """The row of a run whose worker was lost (the same columns as any row)."""
    row = base_row(spec)
    row.update(empty_parameter_columns(spec), status="failed", error=why)
    row["wall_s"] = float("nan")
    return row, []


def _die_with_parent(parent: int) -> None:
    """Make this process end when ``parent`` ends, however it ends."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(Exception):
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() != parent:  # it ended before we asked
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _worker_main(conn: Connection, parent: int, session: Session | None = None) -> None:
    """A worker's loop: receive (spec, shared), send back events and results.

    ``shared`` is what other workers computed that this one has not seen
    (:meth:`Session.shared`); the result goes back with what this run added.
    ``session``: the parent's, when this worker was forked from it.
    """
    _die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops us on Ctrl-C
    if session is not None:
        _forked(session)
    session = worker_session()
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError, KeyboardInterrupt):
            return
        if message is None:
            return
        spec, shared = message
        session.adopt(shared)
        before = set(session.shared())
        result = execute(spec, session, phase=lambda name: conn.send(("phase", name)))
        added = {k: v for k, v in session.shared().items() if k not in before}
        conn.send(("done", result, added))


def _forked(session: Session) -> None:
    """Leave the parent's terminal to the parent and take over its session.

    A forked worker starts with the parent's log handlers and, under a
    progress bar, the bar's stand-ins for stdout/stderr: it writes to the
    real streams with no handler (what reaches a logger at WARNING or above
    is printed by logging's last resort). It keeps the parent's logger
    levels and its handling of Python warnings, so a warning the command
    line hides without ``-v`` stays hidden, as in a serial sweep. BLAS and
    OpenMP libraries were loaded by the parent with its thread count: one
    thread each here, as in a spawned worker (which also keeps GNU OpenMP,
    whose pool does not survive a fork, from using its pool).
    """
    sys.stdout = sys.__stdout__ or sys.stdout
    sys.stderr = sys.__stderr__ or sys.stderr
    loggers = [logging.getLogger(), *logging.Logger.manager.loggerDict.values()]
    for logger in loggers:
        if isinstance(logger, logging.Logger):
            for handler in list(logger.handlers):
                if not isinstance(handler, logging.NullHandler):
                    logger.removeHandler(handler)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)
    _LOCAL.session = session
    _LOCAL.spares = []


def _send(conn: Connection, message: Any) -> None:
    """``conn.send(message)`` with SIGPIPE ignored (main thread; else as is).

    Python ignores SIGPIPE, but libraries may restore its default (gmsh
    does), which kills a process that writes to a worker that just died; with
    it ignored the write fails with an OSError the pool handles.
    """
    try:
        old = signal.signal(signal.SIGPIPE, signal.SIG_IGN)
    except (ValueError, AttributeError):  # not the main thread; no SIGPIPE
        conn.send(message)
        return
    try:
        conn.send(message)
    finally:
        signal.signal(signal.SIGPIPE, signal.SIG_DFL if old is None else old)


def started_ahead() -> list[Worker]:
    """The workers started ahead in this thread by :func:`started`.

    One list a thread, so that a sweep in another thread cannot take them.
    """
    ahead: list[Worker] | None = getattr(_LOCAL, "spares", None)
    if ahead is None:
        ahead = _LOCAL.spares = []
    return ahead


@contextlib.contextmanager
def started(jobs: int) -> Iterator[None]:
    """Start ``jobs`` worker processes now, for the next pool in this block.

    A spawned worker spends its first 0.6-0.7 s importing; started here,
    that overlaps whatever the caller does before it executes runs (planning
    a sweep, computing its truths). The next pool takes what it needs and
    stops the rest; workers no pool took are stopped at the end of the block.
    Where workers are forked (:func:`~idbench.run.executors.start.start_method`)
    this starts none: a worker forked later begins with what the caller did
    meanwhile.
    """
    spares = started_ahead()
    mine: list[Worker] = []
    if jobs and start_method() == "fork":
        jobs = 0
    try:
        with single_thread_environ():
            for _ in range(jobs):
                mine.append(Worker())
                spares.append(mine[-1])
        yield
    finally:
        for w in mine:
            if w in spares:
                spares.remove(w)
                w.stop()


class Worker:
    """One worker process and the run it is busy with (``spec``, or None).

    With a ``session``, the process is forked from this one and works with a
    copy of it, holding its shared products from the start; without, it is
    spawned and builds its own.
    """

    def __init__(self, session: Session | None = None) -> None:
        ctx: Any = mp.get_context("spawn" if session is None else "fork")
        self.conn, child = ctx.Pipe()
        args: tuple[Any, ...] = (child, os.getpid())
        if session is not None:
            args += (session,)
        self.proc = ctx.Process(target=_worker_main, args=args, daemon=True)
        try:
            if session is None:
                with sigint_ignored():  # inherited: a Ctrl-C while it imports is ours
                    self.proc.start()
            else:
                for stream in {sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__}:
                    with contextlib.suppress(Exception):  # else written twice
                        stream.flush()  # type: ignore[union-attr]
                with sigint_ignored(), warnings.catch_warnings():
                    warnings.filterwarnings("ignore", FORK_WARNING, DeprecationWarning)
                    self.proc.start()
        except BaseException:  # no process, or one nobody will stop
            self.kill()
            child.close()
            raise
        child.close()
        self.spec: RunSpec | None = None
        self.deadline: float | None = None
        # keys of the shared products it holds
        self.has: set[Any] = set() if session is None else set(session.shared())

    def give(self, spec: RunSpec, known: dict[Any, Any]) -> None:
        """Start ``spec`` on this worker, with the shared products it lacks."""
        self.spec, self.deadline = spec, None
        new = {k: v for k, v in known.items() if k not in self.has}
        _send(self.conn, (spec, new))
        self.has.update(new)

    def stop(self) -> None:
        """Ask the process to end, then make sure it has.

        It holds nothing to save (results travel through the pipe), so it
        gets a moment to exit, then is killed: a Python process tearing
        down its imports takes 0.1-0.2 s that a sweep should not wait for.
        """
        if self.proc.is_alive():
            with contextlib.suppress(Exception):
                _send(self.conn, None)
        self.proc.join(STOP_GRACE_S)
        self.kill()

    def kill(self) -> None:
        """End the process now."""
        with contextlib.suppress(Exception):
            self.proc.kill()
            self.proc.join(5)
        with contextlib.suppress(Exception):
            self.conn.close()

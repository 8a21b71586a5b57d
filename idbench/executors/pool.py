"""Where runs execute: in this process, or in worker processes we can kill.

(A Dask cluster is the third place: :mod:`idbench.distributed`.)

:func:`execute_all` picks the executor. In-process runs are the fastest and
accept a registry built by hand; worker processes isolate the sweep from what
a run can do to its process (``os._exit``, a segfault, a hang in compiled code
that no signal interrupts). Each worker runs one run at a time, so a worker
that dies is charged to exactly the run it was running, never to a sibling;
a worker whose run overruns ``timeout`` is killed and replaced. Workers die
with the parent process (Linux: ``PR_SET_PDEATHSIG``; elsewhere a watchdog
thread notices the parent has gone).

How workers start (:func:`start_method`): on Linux, when this process runs
one Python thread, they are forked from it once it has planned the sweep, so
they begin with its imports, its built models and its probed truths (nothing
to import or build again: 2 jobs 1.81-1.84x faster than 1 on the default
compare, 1.69x spawned, ``benchmarks/sweep.py``); otherwise, or with
``IDBENCH_START_METHOD=spawn``, they are spawned, as fresh interpreters that
import idbench and the plugins, and start ahead of planning (:func:`started`).
A forked worker drops what belongs to the parent's terminal (its log
handlers, a progress bar's hold on stdout/stderr) and limits BLAS to one
thread, as a spawned one does.
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
from collections.abc import Callable, Generator, Iterator
from multiprocessing.connection import Connection, wait
from typing import Any

from idbench.config import ConfigError
from idbench.harness import execute
from idbench.runspec import RunSpec
from idbench.scoring import base_row, empty_parameter_columns
from idbench.session import Session

log = logging.getLogger(__name__)

RunResult = tuple[dict[str, Any], list[dict[str, Any]]]
THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
START_METHOD_ENV = "IDBENCH_START_METHOD"
"""``fork``, ``spawn`` or ``auto`` (the default): see :func:`start_method`."""
MAX_ATTEMPTS = 2
"""A run whose worker dies is tried this many times in all."""

GRACE_S = 2.0
"""Seconds past ``timeout`` before a run's worker is killed (the run's own
check, a signal inside the worker, gets the first chance)."""

TICK_S = 1.0
"""Seconds at most between calls of :func:`execute_all`'s ``tick`` (it is
also called whenever a worker has news)."""

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


def one_blas_thread() -> Any:
    """A context in which BLAS/OpenMP libraries use one thread.

    Runs are many small dense and sparse solves: threaded BLAS only adds
    overhead (10x slower on a loaded 2-core machine for the full UKF's
    eigendecompositions), and parallelism comes from running runs side by side.
    """
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1)


def worker_lost(spec: RunSpec, why: str) -> RunResult:
    """The row of a run whose worker was lost (the same columns as any row)."""
    row = base_row(spec)
    row.update(empty_parameter_columns(spec), status="failed", error=why)
    row["wall_s"] = float("nan")
    return row, []


def single_thread_env() -> dict[str, str]:
    """Environment that pins BLAS/MKL/OpenMP to one thread per worker."""
    return {k: "1" for k in THREAD_ENV}


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
        yield from _execute_processes(runs, jobs, timeout, session, tick)


# --- worker processes ----------------------------------------------------------


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


@contextlib.contextmanager
def _single_thread_environ() -> Iterator[None]:
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
def _sigint_ignored() -> Iterator[None]:
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


def _spares() -> list[_Worker]:
    """The workers started ahead in this thread by :func:`started`.

    One list a thread, so that a sweep in another thread cannot take them.
    """
    spares: list[_Worker] | None = getattr(_LOCAL, "spares", None)
    if spares is None:
        spares = _LOCAL.spares = []
    return spares


@contextlib.contextmanager
def started(jobs: int) -> Iterator[None]:
    """Start ``jobs`` worker processes now, for the next pool in this block.

    A spawned worker spends its first 0.6-0.7 s importing; started here,
    that overlaps whatever the caller does before it executes runs (planning
    a sweep, computing its truths). The next pool takes what it needs and
    stops the rest; workers no pool took are stopped at the end of the block.
    Where workers are forked (:func:`start_method`) this starts none: a
    worker forked later begins with what the caller did meanwhile.
    """
    spares = _spares()
    mine: list[_Worker] = []
    if jobs and start_method() == "fork":
        jobs = 0
    try:
        with _single_thread_environ():
            for _ in range(jobs):
                mine.append(_Worker())
                spares.append(mine[-1])
        yield
    finally:
        for w in mine:
            if w in spares:
                spares.remove(w)
                w.stop()


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
    (:func:`_forked`). macOS forks unsafely (system frameworks), Windows not
    at all: ``fork`` is refused where the platform has no fork.

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


_FORK_WARNING = r".*multi-threaded, use of fork\(\) may lead to deadlocks"
"""Python 3.12+ warns of a fork while compiled libraries run threads of their
own (BLAS pools): those are fork-safe, and Python threads were checked."""


class _Worker:
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
                with _sigint_ignored():  # inherited: a Ctrl-C while it imports is ours
                    self.proc.start()
            else:
                for stream in {sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__}:
                    with contextlib.suppress(Exception):  # else written twice
                        stream.flush()  # type: ignore[union-attr]
                with _sigint_ignored(), warnings.catch_warnings():
                    warnings.filterwarnings("ignore", _FORK_WARNING, DeprecationWarning)
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


class _Pool:
    """``jobs`` workers, each replaced when it dies or overruns its deadline."""

    def __init__(self, jobs: int, timeout: float | None, session: Session) -> None:
        self.session = session
        self.timeout = timeout
        self.workers: list[_Worker] = []
        spares = _spares()
        try:
            while spares:
                w = spares.pop(0)
                if w.proc.is_alive() and len(self.workers) < jobs:
                    self.workers.append(w)
                else:
                    w.stop()  # dead, or more than this pool needs
            while len(self.workers) < jobs:
                self.workers.append(self._new())
        except BaseException:  # a failed fork, a Ctrl-C: none left running
            self.close()
            raise
        self.attempts: dict[str, int] = {}

    def _new(self) -> _Worker:
        """A new worker: forked from this process if it is safe now, else spawned."""
        return _Worker(self.session if start_method() == "fork" else None)

    def idle(self) -> list[_Worker]:
        """Live workers with nothing to do (dead idle ones are replaced)."""
        for i, w in enumerate(self.workers):
            if w.spec is None and not w.proc.is_alive():
                w.kill()
                self.workers[i] = self._new()
        return [w for w in self.workers if w.spec is None]

    def busy(self) -> list[_Worker]:
        """Workers running a run."""
        return [w for w in self.workers if w.spec is not None]

    def wait(self, most: float | None = None) -> None:
        """Block until a busy worker has news or the nearest deadline passes.

        ``most``: seconds to wait at most.
        """
        busy = self.busy()
        deadlines = [w.deadline for w in busy if w.deadline is not None]
        left = max(0.0, min(deadlines) - time.monotonic()) if deadlines else None
        if most is not None:
            left = most if left is None else min(left, most)
        wait([w.conn for w in busy] + [w.proc.sentinel for w in busy], left)

    def attend(
        self, w: _Worker, queue: list[RunSpec]
    ) -> tuple[RunSpec, RunResult | None, dict[Any, Any]] | None:
        """Handle what ``w`` has to say: None, or (spec, result, shared products).

        A result of None means the run went back to ``queue`` (its worker died
        and it has attempts left).
        """
        spec = w.spec
        assert spec is not None
        if w.conn.poll():
            try:
                message = w.conn.recv()
            except (EOFError, OSError):
                return self._died(w, queue)
            if message[0] == "phase":  # the timeout covers the estimator only
                w.deadline = None
                if message[1] == "estimator" and self.timeout is not None:
                    w.deadline = time.monotonic() + self.timeout + GRACE_S
                return None
            w.spec = None
            w.has.update(message[2])
            return spec, message[1], message[2]
        if not w.proc.is_alive():
            return self._died(w, queue)
        if w.deadline is not None and time.monotonic() >= w.deadline:
            self._replace(w)
            why = (
                f"run exceeded --timeout {self.timeout:g} s and did not stop by "
                "itself (hung in compiled code?): its worker process was killed"
            )
            return spec, worker_lost(spec, why), {}
        return None

    def _died(
        self, w: _Worker, queue: list[RunSpec]
    ) -> tuple[RunSpec, RunResult | None, dict[Any, Any]]:
        spec = w.spec
        assert spec is not None
        w.proc.join(5)
        code = w.proc.exitcode
        self._replace(w)
        n = self.attempts[spec.run_id] = self.attempts.get(spec.run_id, 0) + 1
        log.warning("worker died (exit code %s) running run %s", code, spec.run_id)
        if n < MAX_ATTEMPTS:
            queue.insert(0, spec)
            return spec, None, {}
        why = f"its worker process died (exit code {code}) while running it, {n} times"
        return spec, worker_lost(spec, why), {}

    def _replace(self, w: _Worker) -> None:
        w.kill()
        self.workers[self.workers.index(w)] = self._new()

    def close(self) -> None:
        """Stop every worker (see :meth:`_Worker.stop`)."""
        for w in self.workers:
            w.stop()


LOOKAHEAD = 8
"""Queued runs a free worker considers (the queue starts with the costliest)."""


def _next(
    queue: list[RunSpec],
    busy: list[_Worker],
    known: dict[Any, Any],
    products: Callable[[RunSpec], set[Any]],
) -> int:
    """Index of the run a free worker starts: see :func:`_execute_processes`."""
    underway = set()
    for w in busy:
        assert w.spec is not None
        underway |= products(w.spec)
    underway -= known.keys()
    for i, spec in enumerate(queue[:LOOKAHEAD]):
        if not products(spec) & underway:
            return i
    return 0


def _execute_processes(
    queue: list[RunSpec],
    jobs: int,
    timeout: float | None,
    session: Session,
    tick: Callable[[], None] | None = None,
) -> Iterator[RunResult]:
    """Run on ``jobs`` worker processes; see the module docstring.

    The shared products (truths, reference fits, direct runs) known so far,
    first the ``session``'s: each worker gets those it lacks with its next
    run and returns what it added. A free worker takes the first queued run
    (of the next ``LOOKAHEAD``) that would not compute what a busy worker is
    computing now (:meth:`Session.products`). ``tick``: see :func:`execute_all`.
    """
    queue = list(queue)
    if not queue:
        return
    known = dict(session.shared())
    products = session.products

    def refill() -> None:
        for w in pool.idle():
            if queue:
                spec = queue.pop(_next(queue, pool.busy(), known, products))
                try:
                    w.give(spec, known)
                except OSError:  # it died between the check and now
                    w.spec = None
                    queue.insert(0, spec)

    with _single_thread_environ():
        pool = _Pool(min(jobs, len(queue)) or 1, timeout, session)
        try:
            while queue or pool.busy():
                refill()
                if not pool.busy():  # every hand-over failed: try again
                    continue
                pool.wait(TICK_S if tick else None)
                if tick:
                    try:
                        tick()
                    except Exception as exc:  # a display must not stop the sweep
                        log.warning("progress display failed (%r): not redrawn", exc)
                        tick = None
                finished = []
                for w in pool.busy():
                    news = pool.attend(w, queue)
                    if news is None:
                        continue
                    _, result, added = news
                    known.update(added)
                    if result is not None:
                        finished.append(result)
                refill()  # before the caller stores the results: no worker waits
                yield from finished
        finally:
            pool.close()

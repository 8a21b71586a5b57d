"""A pool of worker processes, each replaced when it dies or overruns its deadline.

A worker whose run overruns ``timeout`` is killed and replaced; a run whose
worker dies is tried again once. Workers pass on to each other what they
compute (:meth:`~idbench.run.session.Session.shared`), and a free worker takes a
run that would not compute what a busy one is computing now.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from multiprocessing.connection import wait
from typing import Any

from idbench.plan.runspec import RunSpec
from idbench.run.executors.start import single_thread_environ, start_method
from idbench.run.executors.worker import RunResult, Worker, started_ahead, worker_lost
from idbench.run.session import Session

log = logging.getLogger(__name__)

MAX_ATTEMPTS = 2
"""A run whose worker dies is tried this many times in all."""

GRACE_S = 2.0
"""Seconds past ``timeout`` before a run's worker is killed (the run's own
check, a signal inside the worker, gets the first chance)."""

TICK_S = 1.0
"""Seconds at most between calls of :func:`idbench.run.executors.execute_all`'s
``tick`` (it is also called whenever a worker has news)."""


class Pool:
    """``jobs`` workers, each replaced when it dies or overruns its deadline."""

    def __init__(self, jobs: int, timeout: float | None, session: Session) -> None:
        self.session = session
        self.timeout = timeout
        self.workers: list[Worker] = []
        spares = started_ahead()
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

    def _new(self) -> Worker:
        """A new worker: forked from this process if it is safe now, else spawned."""
        return Worker(self.session if start_method() == "fork" else None)

    def idle(self) -> list[Worker]:
        """Live workers with nothing to do (dead idle ones are replaced)."""
        for i, w in enumerate(self.workers):
            if w.spec is None and not w.proc.is_alive():
                w.kill()
                self.workers[i] = self._new()
        return [w for w in self.workers if w.spec is None]

    def busy(self) -> list[Worker]:
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
        self, w: Worker, queue: list[RunSpec]
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
        self, w: Worker, queue: list[RunSpec]
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

    def _replace(self, w: Worker) -> None:
        w.kill()
        self.workers[self.workers.index(w)] = self._new()

    def close(self) -> None:
        """Stop every worker (see :meth:`Worker.stop`)."""
        for w in self.workers:
            w.stop()


LOOKAHEAD = 8
"""Queued runs a free worker considers (the queue starts with the costliest)."""


def next_run_index(
    queue: list[RunSpec],
    busy: list[Worker],
    known: dict[Any, Any],
    products: Callable[[RunSpec], set[Any]],
) -> int:
    """Index of the run a free worker starts: see :func:`execute_on_workers`."""
    underway = set()
    for w in busy:
        assert w.spec is not None
        underway |= products(w.spec)
    underway -= known.keys()
    for i, spec in enumerate(queue[:LOOKAHEAD]):
        if not products(spec) & underway:
            return i
    return 0


def execute_on_workers(
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
    computing now (:meth:`Session.products`). ``tick``: see
    :func:`idbench.run.executors.execute_all`.
    """
    queue = list(queue)
    if not queue:
        return
    known = dict(session.shared())
    products = session.products

    def refill() -> None:
        for w in pool.idle():
            if queue:
                spec = queue.pop(next_run_index(queue, pool.busy(), known, products))
                try:
                    w.give(spec, known)
                except OSError:  # it died between the check and now
                    w.spec = None
                    queue.insert(0, spec)

    with single_thread_environ():
        pool = Pool(min(jobs, len(queue)) or 1, timeout, session)
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

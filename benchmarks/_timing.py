"""What the benchmark scripts share: best-of-N timing, races, ratios, one BLAS thread.

Every script reads its arguments with :func:`parser`, times with :func:`best_of`
(one callable) or :func:`race` (several, interleaved so that a machine whose
load drifts slows them alike), often a model's load path (:func:`model_path`),
prints its ratios with :func:`ratio` and runs inside :func:`one_blas_thread`, so
that its figures are one-core figures like the sweep's workers (threaded BLAS on
a shared 2-core machine makes small dense solves several times slower and
noisier).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

T = TypeVar("T")

THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def parser(doc: str) -> argparse.ArgumentParser:
    """The script's argument parser, described by its docstring's first line."""
    return argparse.ArgumentParser(description=doc.splitlines()[0])


def node_counts(doc: str, full: Sequence[int], quick: Sequence[int]) -> Sequence[int]:
    """The mesh sizes (node-count targets) to run, from ``--quick`` / ``--sizes``."""
    ap = parser(doc)
    ap.add_argument("--quick", action="store_true", help=f"only {list(quick)} nodes")
    ap.add_argument("--sizes", type=int, nargs="*", help="node-count targets")
    args = ap.parse_args()
    return args.sizes or (quick if args.quick else full)


def model_path(model: Any, theta: Any) -> Callable[[], Any]:
    """A callable that runs ``model``'s load path at ``theta``: its last state.

    Run once here (symbolic analysis, caches), so the timings that follow
    are of warm runs.
    """

    def run() -> Any:
        u = model.reset()
        for k in range(1, model.n_steps + 1):
            u = model.step(theta, k, u)
        return u

    run()
    return run


def best_of(f: Callable[[], T], repeat: int) -> tuple[float, T]:
    """The least wall time (s) of ``repeat`` calls of ``f``, and the last result."""
    times, [out] = race([f], repeat)
    return times[0], out


def race(
    runs: Sequence[Callable[[], Any]], repeat: int
) -> tuple[list[float], list[Any]]:
    """Best wall time (s) of each callable, calls interleaved ``repeat`` times.

    Returns
    -------
    tuple
        The best time of each and the last result of each, in the order given.
    """
    best = [float("inf")] * len(runs)
    out: list[Any] = [None] * len(runs)
    for _ in range(repeat):
        for i, run in enumerate(runs):
            start = time.perf_counter()
            out[i] = run()
            best[i] = min(best[i], time.perf_counter() - start)
    return best, out


def ratio(numerator: float, denominator: float, digits: int = 2) -> str:
    """``numerator / denominator`` as ``"1.84x"``."""
    return f"{numerator / denominator:.{digits}f}x"


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """BLAS/OpenMP at one thread, here and in the processes started inside.

    The thread-count variables are set (where unset) for child processes and
    this process's loaded thread pools are limited with threadpoolctl.
    """
    from threadpoolctl import threadpool_limits

    for name in THREAD_VARIABLES:
        os.environ.setdefault(name, "1")
    with threadpool_limits(limits=1):
        yield

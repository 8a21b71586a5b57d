"""Run a sweep on a Dask cluster (``pip install 'idbench[dask]'``).

Each run is shipped as its small, picklable :class:`~idbench.plan.runspec.RunSpec`;
a worker builds (once per process) its own registry and models, loads the truth
from the shared cache (computed once by the client before dispatch, see
:func:`idbench.run.compare.prepare`) and sends back the run's rows. Results stream
back in completion order and are written by the client as they arrive, exactly
as in the serial path. A run whose worker dies is retried once by Dask, then
recorded as failed. A lost scheduler (or connection to it) is no run's fault:
the sweep stops with :class:`ClusterLost`, the runs that had not come back are
not recorded, and a rerun resumes them.

Workers should run one BLAS thread each (``OMP_NUM_THREADS=1``,
``MKL_NUM_THREADS=1``) and see the same ``IDBENCH_CACHE_DIR`` (a shared file
system) or compute the truth themselves.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
from collections.abc import Generator
from typing import Any

from idbench.plan.config import ConfigError
from idbench.plan.runspec import RunSpec
from idbench.run.executors.worker import RunResult, run_in_worker, worker_lost

log = logging.getLogger(__name__)

CONNECT_TIMEOUT_S = 10
"""Seconds :func:`connect` tries to reach the scheduler."""

CLOSE_TIMEOUT_S = 5
"""Seconds :func:`execute_on_dask` waits for its client to close."""


class ClusterLost(RuntimeError):
    """The Dask scheduler, or the connection to it, was lost mid-sweep.

    Attributes
    ----------
    address
        The scheduler's address.
    """

    def __init__(self, address: str, detail: str) -> None:
        super().__init__(f"lost the Dask scheduler at {address}: {detail}")
        self.address = address


def connect(address: str) -> Any:
    """A :class:`distributed.Client` of the scheduler at ``address``.

    Raises
    ------
    ConfigError
        Without ``distributed``, or if nobody answers at ``address``.
    """
    try:
        from distributed import Client
    except ImportError:
        raise ConfigError(
            f"--scheduler {address!r} needs Dask distributed: "
            "pip install 'idbench[dask]'"
        ) from None
    try:
        return Client(address, timeout=CONNECT_TIMEOUT_S)
    except Exception as exc:  # bad address (ValueError), nobody there (OSError)
        raise ConfigError(
            f"--scheduler {address!r}: cannot connect ({type(exc).__name__}: {exc}); "
            "expected tcp://HOST:PORT of a running Dask scheduler"
        ) from None


def quiet_logging() -> None:
    """Silence distributed's own log messages below CRITICAL (the CLI without -v).

    Importing ``distributed`` configures its loggers (``distributed``,
    ``distributed.client``, ...), so this imports it first, then lowers them;
    a lost scheduler is then said once, by idbench, not by its reconnection
    attempts' tracebacks.
    """
    try:
        import distributed  # noqa: F401  (configures its loggers)
    except ImportError:
        return
    for name in list(logging.root.manager.loggerDict):
        if name == "distributed" or name.startswith("distributed."):
            logging.getLogger(name).setLevel(logging.CRITICAL)


def _lost(exc: BaseException, client: Any) -> bool:
    """Whether ``exc`` says the scheduler or the connection is gone (no run's fault)."""
    cancelled = (concurrent.futures.CancelledError, asyncio.CancelledError)
    if isinstance(exc, (*cancelled, OSError, TimeoutError)):
        return True  # a run cancelled, the comm closed (CommClosedError is an OSError)
    return getattr(client, "status", "running") not in ("running", "newly-created")


def execute_on_dask(
    runs: list[RunSpec], client: Any, address: str
) -> Generator[RunResult, None, None]:
    """Execute ``runs`` through ``client`` of ``address`` (see :func:`connect`).

    Yields each run's result as it finishes.

    The client is closed when the generator ends (also when it is closed).

    Raises
    ------
    ClusterLost
        When the scheduler or the connection is lost; runs not yet yielded
        were not recorded by anyone and should run again.
    """
    from distributed import as_completed

    try:
        futures = {
            client.submit(
                run_in_worker, spec, key=f"idbench-run-{spec.run_id}", retries=1
            ): spec
            for spec in runs
        }
        for fut in as_completed(futures):
            spec = futures[fut]
            try:
                result = fut.result()
            except Exception as exc:  # KilledWorker after retries, lost connection
                if _lost(exc, client):
                    raise ClusterLost(address, f"{type(exc).__name__}") from None
                log.warning("run %s lost on the cluster: %s", spec.run_id, exc)
                result = worker_lost(
                    spec, f"lost on the cluster: {type(exc).__name__}: {exc}"
                )
            finally:
                fut.release()
            yield result
    finally:
        try:
            client.close(timeout=CLOSE_TIMEOUT_S)
        except Exception as exc:  # a scheduler gone: nothing left to close
            log.debug("closing the Dask client: %r", exc)

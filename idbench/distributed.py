"""Run a sweep on a Dask cluster (``pip install 'idbench[dask]'``).

Each run is shipped as its small, picklable :class:`~idbench.runspec.RunSpec`;
a worker builds (once per process) its own registry and models, loads the truth
from the shared cache (computed once by the client before dispatch, see
:func:`idbench.sweep.prepare`) and sends back the run's rows. Results stream
back in completion order and are written by the client as they arrive, exactly
as in the serial path. A run whose worker dies is retried once by Dask, then
recorded as failed.

Workers should run one BLAS thread each (``OMP_NUM_THREADS=1``,
``MKL_NUM_THREADS=1``) and see the same ``IDBENCH_CACHE_DIR`` (a shared file
system) or compute the truth themselves.
"""

from __future__ import annotations

import logging
from collections.abc import Generator
from typing import Any

from idbench.config import ConfigError
from idbench.executors import RunResult, run_in_worker, worker_lost
from idbench.runspec import RunSpec

log = logging.getLogger(__name__)

def _client(address: str) -> Any:
    try:
        from distributed import Client
    except ImportError:
        raise ConfigError(
            f"--scheduler {address!r} needs Dask distributed: "
            "pip install 'idbench[dask]'"
        ) from None
    try:
        return Client(address, timeout="10s")
    except Exception as exc:  # bad address (ValueError), nobody there (OSError)
        raise ConfigError(
            f"--scheduler {address!r}: cannot connect ({type(exc).__name__}: {exc}); "
            "expected tcp://HOST:PORT of a running Dask scheduler"
        ) from None


def execute_on_dask(
    runs: list[RunSpec], address: str
) -> Generator[RunResult, None, None]:
    """Execute ``runs`` on the Dask scheduler at ``address``; yield as they finish."""
    from distributed import as_completed

    client = _client(address)
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
                yield fut.result()
            except Exception as exc:  # KilledWorker after retries, lost connection
                log.warning("run %s lost on the cluster: %s", spec.run_id, exc)
                yield worker_lost(
                    spec, f"lost on the cluster: {type(exc).__name__}: {exc}"
                )
            finally:
                fut.release()
    finally:
        client.close()

"""Run a comparison: validate, prepare shared inputs, execute, store.

:func:`compare` is the Python API behind ``idbench compare``. Runs go to an
executor (serial, local processes, or a Dask cluster); each finished run is
written to the results directory as it arrives, so an interrupted sweep keeps
every finished run and a rerun with the same directory skips them.
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import logging
import multiprocessing as mp
import os
import platform
import sys
import tempfile
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from idbench.config import CompareConfig, ConfigError, suggest
from idbench.harness import RunSpec, Session, base_row, execute, expand
from idbench.interfaces import FloatArray
from idbench.plugins import Registry, build_registry
from idbench.results import ResultStore

log = logging.getLogger(__name__)

RunResult = tuple[dict[str, Any], list[dict[str, Any]]]
THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
MAX_ATTEMPTS = 2


@dataclass(frozen=True)
class Plan:
    """A validated comparison: its runs and what they will cost."""

    config: CompareConfig
    runs: list[RunSpec]
    nodes: dict[str, int]
    solves: int


def plan(config: CompareConfig, session: Session) -> Plan:
    """Validate ``config`` against the registry and build its runs.

    Raises
    ------
    ConfigError
        Naming the first bad value and what is allowed.
    """
    reg = session.registry
    _known("model", [config.model], reg.models)
    _known("estimator", config.estimators, reg.estimators)
    _known("scenario", config.scenarios, reg.scenarios)
    _known("reference estimator", [config.reference], reg.estimators)
    for name, settings in config.estimator_settings.items():
        _known("estimator (in settings)", [name], reg.estimators)
        cls = reg.estimator(name)
        fields = {f.name for f in dataclasses.fields(cls)}
        for key in settings:
            if key not in fields:
                raise ConfigError(
                    f"estimator {name!r} has no setting {key!r}{suggest(key, fields)}; "
                    f"allowed: {', '.join(sorted(fields))}"
                )
        try:
            cls(**settings)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"estimator {name!r}: {exc}") from None
        except Exception as exc:  # a plugin's own bug, still one clean line
            raise ConfigError(
                f"estimator {name!r} (plugin {reg.estimators[name].plugin!r}) "
                f"raised {type(exc).__name__}: {exc}"
            ) from None
    runs = expand(config)
    nodes: dict[str, int] = {}
    solves = 0
    for mesh in (*config.meshes, config.truth_mesh):
        try:
            model = session.model(
                runs[0], mesh, role="truth" if mesh == config.truth_mesh else "est"
            )
        except ConfigError:
            raise
        except (ValueError, OSError, RuntimeError) as exc:
            text = str(exc)  # readers often name the mesh already
            message = text if repr(mesh) in text else f"mesh {mesh!r}: {text}"
            raise ConfigError(message) from None
        except Exception as exc:  # a model plugin's own bug, still one clean line
            raise ConfigError(
                f"model {config.model!r} (plugin {reg.models[config.model].plugin!r}) "
                f"raised {type(exc).__name__} building mesh {mesh!r}: {exc}"
            ) from None
        nodes[mesh] = int(getattr(model, "n_nodes", 0))
    for spec in runs:
        try:
            est = reg.estimator(spec.estimator)(**dict(spec.settings))
        except Exception as exc:  # the run will fail and say so; plan on
            log.warning("estimator %r cannot be built: %s", spec.estimator, exc)
            est = None
        model = session.model(spec, spec.mesh)
        guess = getattr(est, "estimate_solves", None)
        n_state = int(getattr(model, "n_state", 0))
        p = model.parameters.p
        solves += int(guess(n_state, p, spec.steps)) if guess else 2 * spec.steps
    return Plan(config, runs, nodes, solves)


def _known(kind: str, names: Any, table: dict[str, Any]) -> None:
    for name in names:
        if name not in table:
            allowed = ", ".join(sorted(table)) or "none registered"
            raise ConfigError(
                f"unknown {kind} {name!r}{suggest(name, table)}; allowed: {allowed}"
            )


def manifest(config: CompareConfig) -> dict[str, Any]:
    """Versions, solver backend and thread settings, for the results folder."""
    versions: dict[str, str | None] = {}
    for dist in (
        "idbench",
        "numpy",
        "scipy",
        "scikit-fem",
        "filterpy",
        "pandas",
        "pypardiso",
        "pluggy",
        "distributed",
    ):
        try:
            versions[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            versions[dist] = None
    return {
        "versions": versions,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "solver": os.environ.get("IDBENCH_SOLVER", "auto"),
        "threads": {k: os.environ.get(k) for k in THREAD_ENV},
        "cpu_count": os.cpu_count(),
    }


def compare(
    config: CompareConfig | None = None,
    out: str | Path | None = None,
    *,
    jobs: int = 1,
    scheduler: str | None = None,
    registry: Registry | None = None,
    progress: Callable[[int, int, dict[str, Any]], None] | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Run a comparison and return its runs and traces tables.

    Parameters
    ----------
    config
        The comparison (default: :class:`CompareConfig` defaults).
    out
        Results directory; finished runs in it are skipped. Default: a
        temporary directory, removed afterwards.
    jobs
        Local worker processes (1: serial, in this process).
    scheduler
        Address of a Dask scheduler (``tcp://host:port``); needs ``distributed``.
    registry
        The plugin registry (default: built from the installed plugins). Only
        the serial executor can use a registry built by hand.
    progress
        Called as ``progress(done, total, run_row)`` after each run.

    Returns
    -------
    tuple of pandas.DataFrame
        ``runs`` (one row per run) and ``traces`` (one row per run and step).
    """
    config = config or CompareConfig()
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ConfigError(f"jobs {jobs!r}: must be a whole number >= 1")
    session = Session(registry or build_registry())
    the_plan = plan(config, session)
    if out is None:
        with tempfile.TemporaryDirectory(prefix="idbench-") as tmp:
            return _compare(the_plan, Path(tmp), session, jobs, scheduler, progress)
    return _compare(the_plan, Path(out), session, jobs, scheduler, progress)


def _compare(
    the_plan: Plan,
    out: Path,
    session: Session,
    jobs: int,
    scheduler: str | None,
    progress: Callable[[int, int, dict[str, Any]], None] | None,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    config = the_plan.config
    store = ResultStore(out, config.to_dict(), manifest(config))
    done = store.finished()
    retry = store.failed()
    if retry:
        log.info("retrying %d run(s) that failed before", len(retry))
    done -= retry
    pending = [r for r in the_plan.runs if r.run_id not in done]
    total = len(the_plan.runs)
    count = total - len(pending)
    if pending:
        prepare(pending, session)
    for row, traces in _execute_all(pending, session, jobs, scheduler):
        store.write(row, traces)
        count += 1
        if progress:
            progress(count, total, row)
        else:
            log.info(
                "run %d/%d: %s on %s, %s: %s",
                count, total, row["estimator"], row["mesh"], row["scenario"],
                row["status"],
            )  # fmt: skip
    return store.consolidate([r.run_id for r in the_plan.runs])


def prepare(runs: list[RunSpec], session: Session) -> None:
    """Compute each truth the runs need once, here, so workers load it from disk."""
    seen = set()
    for spec in runs:
        scen = session.registry.scenario(spec.scenario)
        for name in (spec.scenario, scen.transfer):
            key = (
                name,
                spec.truth_mesh,
                spec.steps,
                spec.nu,
                spec.parameters,
                spec.model_options,
                spec.E_true,
            )
            if name and name in session.registry.scenarios and key not in seen:
                seen.add(key)
                session.truth(spec, name)


def _execute_all(
    runs: list[RunSpec], session: Session, jobs: int, scheduler: str | None
) -> Iterator[RunResult]:
    if scheduler:
        from idbench.distributed import execute_on_dask

        yield from execute_on_dask(runs, scheduler)
    elif jobs == 1:
        for spec in runs:
            yield execute(spec, session)
    else:
        yield from _execute_processes(runs, jobs)


_WORKER_SESSION: Session | None = None


def _worker_init() -> None:
    global _WORKER_SESSION
    _WORKER_SESSION = Session()


def run_in_worker(spec: RunSpec) -> RunResult:
    """Execute ``spec`` with this process's session (built on first use)."""
    global _WORKER_SESSION
    if _WORKER_SESSION is None:
        _WORKER_SESSION = Session()
    return execute(spec, _WORKER_SESSION)


def run_with_hint(
    spec: RunSpec, reference: FloatArray | None
) -> tuple[RunResult, FloatArray | None]:
    """:func:`run_in_worker`, seeded with E_ref another worker already fitted.

    Returns the result and this run's E_ref (None if never fitted), so the
    parent can pass it on to later runs on the same data.
    """
    global _WORKER_SESSION
    if _WORKER_SESSION is None:
        _WORKER_SESSION = Session()
    if reference is not None:
        _WORKER_SESSION.remember_reference(spec, reference)
    result = execute(spec, _WORKER_SESSION)
    return result, _WORKER_SESSION.known_reference(spec)


def interleave(runs: list[RunSpec]) -> list[RunSpec]:
    """Runs ordered so that consecutive ones use different data.

    One run of each E_ref key first, then the second of each, ...: the first
    runs a pool starts fit different references, and later runs on the same
    data receive the fit (see :func:`run_with_hint`) instead of repeating it.
    """
    groups: dict[Any, list[RunSpec]] = {}
    for spec in runs:
        groups.setdefault(Session.reference_key(spec), []).append(spec)
    order: list[RunSpec] = []
    columns = list(groups.values())
    for i in range(max((len(c) for c in columns), default=0)):
        order.extend(c[i] for c in columns if i < len(c))
    return order


def single_thread_env() -> dict[str, str]:
    """Environment that pins BLAS/MKL/OpenMP to one thread per worker."""
    return {k: "1" for k in THREAD_ENV}


def _execute_processes(runs: list[RunSpec], jobs: int) -> Iterator[RunResult]:
    """Run on a local process pool; a dead worker costs only its runs in flight.

    At most ``jobs`` runs are in flight; each is submitted with the E_ref of
    its data if an earlier run has fitted it (so every reference is fitted
    once per sweep, not once per worker).
    """
    attempts = {r.run_id: 0 for r in runs}
    queue = interleave(runs)
    known: dict[Any, FloatArray] = {}
    saved = {k: os.environ.get(k) for k in THREAD_ENV}
    os.environ.update(single_thread_env())
    try:
        while queue:
            ctx = mp.get_context("spawn")
            with ProcessPoolExecutor(
                jobs, mp_context=ctx, initializer=_worker_init
            ) as pool:
                in_flight: dict[Future[Any], RunSpec] = {}
                broken = False
                while (queue or in_flight) and not broken:
                    while queue and len(in_flight) < jobs:
                        spec = queue.pop(0)
                        hint = known.get(Session.reference_key(spec))
                        in_flight[pool.submit(run_with_hint, spec, hint)] = spec
                    finished, _ = wait(set(in_flight), return_when=FIRST_COMPLETED)
                    for fut in finished:
                        spec = in_flight.pop(fut)
                        try:
                            result, ref = fut.result()
                        except BrokenProcessPool:
                            broken = True
                            attempts[spec.run_id] += 1
                            if attempts[spec.run_id] >= MAX_ATTEMPTS:
                                yield worker_lost(spec)
                            else:
                                queue.insert(0, spec)
                            continue
                        if ref is not None:
                            known[Session.reference_key(spec)] = ref
                        yield result
                if broken:  # the pool is gone: requeue what was in flight
                    queue[:0] = list(in_flight.values())
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def worker_lost(spec: RunSpec) -> RunResult:
    """The row of a run whose worker died twice."""
    row = base_row(spec)
    row.update(status="failed", error="worker process died while running it (twice)")
    return row, []

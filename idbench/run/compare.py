"""Run a comparison: validate, prepare shared inputs, execute, store.

:func:`compare` is the Python API behind ``idbench compare``. Runs go to an
executor (serial, local processes, or a Dask cluster); each finished run is
written to the results directory as it arrives, so an interrupted sweep keeps
every finished run and a rerun with the same directory skips them.
"""

from __future__ import annotations

import importlib.metadata
import logging
import os
import platform
import sys
import tempfile
from collections.abc import Callable, Generator, Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from idbench.core.capabilities import tick_of
from idbench.core.interfaces import ModelFailure
from idbench.observe import kinds
from idbench.plan.check import Plan, plan
from idbench.plan.config import CompareConfig, ConfigError
from idbench.plan.runspec import RunSpec
from idbench.registry.registry import Registry, build_registry
from idbench.run.executors import (
    THREAD_ENV,
    ClusterLost,
    RunResult,
    connect,
    execute_all,
    execute_on_dask,
    start_method,
    started,
)
from idbench.run.session import Session
from idbench.store import surfaces
from idbench.store.results import ResultsError, ResultStore

log = logging.getLogger(__name__)


def runs_of(config: CompareConfig, registry: Registry | None = None) -> list[RunSpec]:
    """The runs of ``config``, resolved and validated (see :func:`plan`)."""
    return plan(config, Session(registry or build_registry())).runs


def sense(spec: RunSpec, session: Session) -> None:
    """Compute the run's noise-free readings now (a failure is a ConfigError)."""
    obs = session.observation_model(spec)
    for name, block in kinds.leaves(obs):
        try:
            session.sensed(spec, block)
        except (ValueError, ArithmeticError) as exc:
            what = name or spec.observe
            raise ConfigError(f"observe {what!r} on the truth: {exc}") from None


def _identity(config: CompareConfig, the_plan: Plan) -> dict[str, Any]:
    """The configuration an output folder must match, resolved.

    The model's settings and the true values as resolved (defaults filled
    in), so that giving a default explicitly (``--nu 0.45``, ``--E-true
    5000``) or not is the same comparison; execution settings left out.
    """
    settings = config.to_dict()
    if the_plan.runs:
        setup = the_plan.runs[0].setup
        tables = settings.setdefault("model_settings", {})
        tables[config.model] = dict(setup.model_settings)  # without execution
        settings["true"] = dict(setup.true)
        if setup.data:  # what the recording holds, not only where it lies
            settings["data_sha256"] = setup.data[1]
    return settings


def manifest(plugins: Mapping[str, str], reg: Registry) -> dict[str, Any]:
    """Versions and machine settings, for the results folder.

    The core's own packages, then the packages each plugin of ``plugins`` (the
    plugins the runs use) reported through ``register_versions``; the plugins'
    own versions are in ``plugins``.
    """
    versions: dict[str, str | None] = {}
    for dist in ("idbench", "numpy", "scipy", "pandas", "pluggy", "distributed"):
        try:
            versions[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            versions[dist] = None
    for plugin in plugins:
        versions.update(reg.packages.get(plugin, {}))
    return {
        "versions": versions,
        "python": sys.version.split()[0],
        "platform": platform.platform(),
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
    wait: bool = False,
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
        Local worker processes (1: serial, in this process; with a registry
        built by hand, runs always execute in this process).
    scheduler
        Address of a Dask scheduler (``tcp://host:port``); needs ``distributed``.
    registry
        The plugin registry (default: built from the installed plugins). A
        registry built by hand works only in this process: with it, runs
        execute here whatever ``jobs`` and ``timeout`` say (the timeout then
        interrupts Python code only, not a hang in compiled code).
    progress
        Called as ``progress(done, total, run_row)`` after each run; if it
        has a ``tick()`` method, that is called about once a second while
        worker processes run (to redraw a clock).
    wait
        If another process is writing ``out``, wait until it is done; by
        default that is refused (:class:`~idbench.store.lock.FolderBusy`, naming
        the other process). Only one process at a time writes a folder.

    Returns
    -------
    tuple of pandas.DataFrame
        ``runs`` (one row per run) and ``traces`` (one row per run and step).
    """
    config = config or CompareConfig()
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ConfigError(f"jobs {jobs!r}: must be a whole number >= 1")
    isolate = registry is None  # workers can rebuild only an installed registry
    if isolate and not scheduler and (jobs > 1 or config.timeout is not None):
        start_method()  # a bad IDBENCH_START_METHOD: refused before any work
    session = Session(registry or build_registry())
    # spawned workers start importing while this process plans and prepares
    # (at most one a core: a pool that needs more starts them itself); forked
    # ones are forked when the pool needs them (see executors.start_method)
    ahead = min(jobs, os.cpu_count() or 1) if isolate and jobs > 1 else 0
    with started(0 if scheduler else ahead):
        the_plan = plan(config, session)
        args = (session, jobs, scheduler, progress, isolate, wait)
        if out is None:
            with tempfile.TemporaryDirectory(prefix="idbench-") as tmp:
                return _compare(the_plan, Path(tmp), *args)
        return _compare(the_plan, Path(out), *args)


def _compare(
    the_plan: Plan,
    out: Path,
    session: Session,
    jobs: int,
    scheduler: str | None,
    progress: Callable[[int, int, dict[str, Any]], None] | None,
    isolate: bool,
    wait: bool,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    config = the_plan.config
    execution = dict(the_plan.runs[0].setup.execution) if the_plan.runs else {}
    with ResultStore(
        out,
        _identity(config, the_plan),
        {
            **manifest(the_plan.plugins, session.registry),
            "execution": execution,
            "plugins": the_plan.plugins,
            "inputs": the_plan.inputs,
        },
        wait=wait,
    ) as store:
        stale = surfaces.check(out, the_plan.inputs)  # what the runs showed
        if stale:
            raise ResultsError(f"{stale}; use another --out DIR or delete it")
        return _run(the_plan, store, session, jobs, scheduler, progress, isolate)


def _run(
    the_plan: Plan,
    store: ResultStore,
    session: Session,
    jobs: int,
    scheduler: str | None,
    progress: Callable[[int, int, dict[str, Any]], None] | None,
    isolate: bool,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Execute the runs ``store`` lacks, store each, consolidate."""
    config = the_plan.config
    stored = store.scan()
    done = {run_id for run_id, failed in stored.items() if not failed}
    if len(done) < len(stored):
        log.info("retrying %d run(s) that failed before", len(stored) - len(done))
    pending = dispatch_order(
        [r for r in the_plan.runs if r.run_id not in done], the_plan.work
    )
    total = len(the_plan.runs)
    count = total - len(pending)
    client = None
    if pending:
        try:
            if scheduler:  # before the truths are computed: a wrong address fails fast
                client = connect(scheduler)
            prepare(pending, session)
            store_truth_surfaces(pending, session, store.root, the_plan.inputs)
        except BaseException as exc:
            if client is not None:
                client.close()
            if isinstance(exc, ConfigError):
                store.discard_if_unused()  # so fixed settings can use the folder
            raise
    results: Generator[RunResult, None, None]
    if scheduler:
        results = execute_on_dask(pending, client, scheduler) if pending else _none()
    else:
        results = execute_all(
            pending,
            session,
            jobs=jobs if isolate else 1,
            timeout=config.timeout if isolate else None,
            tick=tick_of(progress),
        )
    order = [r.run_id for r in the_plan.runs]
    try:
        for row, traces in results:
            shown = row.pop(surfaces.ROW_KEY, None)  # before its parts: see there
            if shown is not None:
                surfaces.write_run(store.root, shown, the_plan.inputs)
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
    except KeyboardInterrupt:  # keep the tables of what finished, then stop
        results.close()
        store.consolidate(order)
        raise
    except ClusterLost as exc:  # the runs not back are not stored: a rerun does them
        if store.finished():
            store.consolidate(order)
        else:
            store.discard_if_unused()
        raise ClusterLost(
            exc.address,
            f"{count} of {total} runs stored; rerun the same command to resume",
        ) from None
    return store.consolidate(order)


def _none() -> Generator[RunResult, None, None]:
    """No results (a resume with nothing left to run)."""
    yield from ()


def prepare(runs: list[RunSpec], session: Session) -> None:
    """Compute and probe each truth the runs need once, here.

    Workers then receive them probed (:meth:`Session.shared`); a truth the
    disk cache lacks is simulated once, not once per worker.
    """
    seen = set()
    for spec in runs:
        scen = session.scenario(spec, spec.scenario)
        if spec.setup.data:  # a recording: nothing to simulate or sense
            continue
        for name in (spec.scenario, scen.transfer):
            key = spec.truth_product_key(name) if name else None
            if name and key not in seen:
                seen.add(key)
                try:
                    session.truth(spec, name)
                except ModelFailure as exc:
                    raise ConfigError(
                        f"the truth ({spec.setup.truth_mesh}, {name}) cannot be "
                        f"simulated with these settings: {exc}"
                    ) from None
                except (ValueError, OSError) as exc:  # its model cannot be built
                    raise ConfigError(
                        f"the truth ({spec.setup.truth_mesh}, {name}): {exc}"
                    ) from None
        if spec.observed_otherwise():
            sense(spec, session)


def store_truth_surfaces(
    runs: list[RunSpec], session: Session, root: Path, inputs: list[Any]
) -> None:
    """Store the truth's surface of each data set of ``runs`` once (if missing)."""
    for spec in runs:
        if not spec.setup.data:  # a recording has no truth field
            mesh, scenario = spec.setup.truth_mesh, spec.scenario
            surfaces.write_truth(
                root, spec.truth_product_key(scenario),
                spec.model_key(mesh, scenario, "truth"),
                session.model(spec, mesh, scenario, role="truth"),
                session.truth(spec).states, inputs,
            )  # fmt: skip


def dispatch_order(runs: list[RunSpec], work: dict[str, float]) -> list[RunSpec]:
    """The order in which runs start.

    The reference estimator's own runs first: each is its data's reference
    fit, which later runs on the same data reuse instead of fitting again.
    Then the others. Within each group the costliest first (by ``work``, the
    plan's guess), so that no long run starts last and keeps the sweep going
    on one worker while the others idle; runs of equal cost alternate
    between data sets (:func:`interleave`).
    """

    def key(spec: RunSpec) -> tuple[bool, float]:
        own_reference = spec.estimator == spec.setup.reference and not spec.settings
        return not own_reference, -work.get(spec.run_id, 0.0)

    return sorted(interleave(runs), key=key)


def interleave(runs: list[RunSpec]) -> list[RunSpec]:
    """Runs ordered so that consecutive ones use different data.

    One run of each E_ref key first, then the second of each, ...: the first
    runs a pool starts fit different references, and later runs on the same
    data receive the fit instead of repeating it.
    """
    groups: dict[Any, list[RunSpec]] = {}
    for spec in runs:
        groups.setdefault(spec.reference_key(), []).append(spec)
    order: list[RunSpec] = []
    columns = list(groups.values())
    for i in range(max((len(c) for c in columns), default=0)):
        order.extend(c[i] for c in columns if i < len(c))
    return order

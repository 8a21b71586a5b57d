"""Run a comparison: validate, prepare shared inputs, execute, store.

:func:`compare` is the Python API behind ``idbench compare``. Runs go to an
executor (serial, local processes, or a Dask cluster); each finished run is
written to the results directory as it arrives, so an interrupted sweep keeps
every finished run and a rerun with the same directory skips them.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.metadata
import json
import logging
import os
import platform
import sys
import tempfile
from collections.abc import Callable, Generator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from idbench import observe, recording
from idbench.capabilities import bounds_of, n_nodes_of, needs_observed_of
from idbench.config import CompareConfig, ConfigError
from idbench.discrepancy import CalibrationSettings
from idbench.executors import (
    THREAD_ENV,
    ClusterLost,
    RunResult,
    connect,
    execute_all,
    execute_on_dask,
    start_method,
    started,
)
from idbench.files import stable_hash
from idbench.interfaces import ForwardModel, ModelFailure, ModelSpec
from idbench.observing import resolve as resolve_observations
from idbench.observing import sense
from idbench.plugins import Registry, build_registry, used_plugins
from idbench.posterior import PosteriorSettings, check_budget
from idbench.results import ResultStore
from idbench.runspec import RunSpec, Setup, expand
from idbench.session import Session
from idbench.settings import (
    build_settings,
    execution_items,
    model_settings,
    proposed_scenarios,
    settings_identity,
    settings_items,
    suggest,
    true_values,
)
from idbench.validity import check_prior, check_truth_mesh

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Plan:
    """A validated comparison: its runs and what they will cost.

    Attributes
    ----------
    config
        The resolved configuration.
    runs
        Every run, in table order.
    nodes
        Nodes per mesh (0 where the model does not say).
    solves
        The estimators' guess of the forward model steps of all runs.
    work
        Per run id, its guessed solves times its model's state size: a
        relative cost, for starting the costliest runs first.
    inputs
        What each model of the comparison reads, one entry per model
        (``key``, ``role``, ``mesh``, ``scenario`` and its ``describe()``),
        for the manifest (see :func:`model_inputs`).
    plugins
        Plugin -> version of the plugins whose model, estimators and
        scenarios the runs use.
    """

    config: CompareConfig
    runs: list[RunSpec]
    nodes: dict[str, int]
    solves: int
    work: dict[str, float] = field(default_factory=dict)
    inputs: list[dict[str, Any]] = field(default_factory=list)
    plugins: dict[str, str] = field(default_factory=dict)


def plan(config: CompareConfig, session: Session) -> Plan:
    """Validate ``config`` against the registry, resolve it and build its runs.

    Every default the config leaves open is filled from what the plugins
    registered (:meth:`CompareConfig.resolve`); the true values from the
    model's parameter defaults and ``config.true``.

    Raises
    ------
    ConfigError
        Naming the first bad value and what is allowed.
    """
    reg = session.registry
    rec = None
    if config.data:  # a recording fixes the data axes; there is no truth mesh
        config, rec = recording.configure(config)
    config = config.resolve(reg)
    assert config.model and config.scenarios and config.meshes and config.truth_mesh
    _known("model", [config.model], reg.models, reg)
    settings = model_settings(
        reg, config.model, config.model_settings.get(config.model, {})
    )
    own = proposed_scenarios(settings, config.model)  # e.g. a body file's
    if own:
        reg = reg.with_scenarios(list(own), reg.models[config.model].plugin)
    loads = [sc.name for sc in own] if own else list(reg.scenarios)
    if rec is not None:
        recording.check_body(rec, None, loads)
    _known("estimator", config.estimators, reg.estimators, reg)
    _known("scenario", config.scenarios, reg.scenarios, reg)
    _known("reference estimator", [config.reference], reg.estimators, reg)
    for name in config.scenarios:
        target = reg.scenario(name).transfer
        if target and target not in reg.scenarios:
            raise ConfigError(
                f"scenario {name!r} names transfer scenario {target!r}, which is not "
                f"registered; allowed: {', '.join(sorted(reg.scenarios))}"
            )
    for name in config.model_settings:
        _known("model (in model settings)", [name], reg.models, reg)
        model_settings(reg, name, config.model_settings[name])
    for name, given in config.estimator_settings.items():
        _check_estimator_settings(reg, name, given)
    probe = _build(reg, config, config.meshes[0], settings)
    _check_posterior(config, probe.parameters.p)
    _check_calibration(config, reg)
    check_prior(probe.parameters, config.prior, config.model)  # type: ignore[arg-type]
    setup = Setup(
        model=config.model,
        model_settings=settings_items(settings),
        execution=execution_items(settings),
        identity=settings_identity(settings),
        truth_mesh=config.truth_mesh,
        steps=config.steps,
        true=(
            true_values(probe.parameters, config.true, config.model)
            if rec is None
            else recording.true_values(rec, probe.parameters.names)
        ),
        prior=(float(config.prior[0]), float(config.prior[1])),  # type: ignore[index]
        reference=config.reference,  # type: ignore[arg-type]
        data=() if rec is None else (str(rec.path), rec.digest),
    )
    runs = expand(config, setup)
    nodes: dict[str, int] = {}
    models: dict[str, ForwardModel] = {}
    for mesh in (*config.meshes, *([config.truth_mesh] if rec is None else [])):
        role = "truth" if mesh == config.truth_mesh else "est"
        build = functools.partial(session.model, runs[0], mesh, role=role)
        models[mesh] = model = _build(reg, config, mesh, settings, build)
        nodes[mesh] = int(n_nodes_of(model) or 0)
    for mesh in config.meshes if rec is None else ():
        truth = models[config.truth_mesh]
        check_truth_mesh(truth, config.truth_mesh, models[mesh], mesh)
    if rec is not None:
        bounds = bounds_of(models[config.meshes[0]])
        recording.check_body(rec, bounds, loads)
        obs = observe.build(rec.observe, rec.observe_settings, reg)
        recording.check_frames(rec, obs)
    if config.observe != ("markers",) or config.observe_settings:
        built = list(models.values())
        runs = expand(config, setup, resolve_observations(config, reg, built))
    _check_corrected(runs, config)
    runs, inputs = model_inputs(runs, session, config, settings, reg)
    solves, work = 0, {}
    for spec in runs:
        model = session.model(spec, spec.mesh)
        _check_observed(spec, model, session)
        n_state = model.reset().size
        guess = _guess_solves(reg, spec, n_state, model.parameters.p)
        work[spec.run_id] = float(guess) * n_state
        solves += guess
    transfers = [reg.scenario(n).transfer for n in config.scenarios]
    scenarios = {*config.scenarios, *transfers}
    plugins = used_plugins(
        reg,
        ("models", [config.model]),
        ("estimators", [*(config.estimators or ()), config.reference or ""]),
        ("scenarios", sorted(n for n in scenarios if n)),
    )
    return Plan(config, runs, nodes, solves, work, inputs, plugins)


def _check_observed(spec: RunSpec, model: ForwardModel, session: Session) -> None:
    """Refuse a run whose observation uses none of the members its model needs.

    See :class:`~idbench.interfaces.ObservationNeedsModel` (a solid whose tool
    moves by a prescribed displacement needs its ``reaction``: the force).

    Raises
    ------
    ConfigError
        One line naming the scenario and the observations that would do.
    """
    needs = needs_observed_of(model)
    if not needs:
        return
    used = {m for _, b in observe.leaves(session.observation_model(spec))
            for m in b.requires}  # fmt: skip
    if used & set(needs):
        return
    would = []
    for kind in sorted(observe.kinds(session.registry)):
        try:
            block = observe.build(kind, {}, session.registry)
        except (ConfigError, TypeError, ValueError):  # a kind with required settings
            continue
        if set(block.requires) & set(needs):
            would.append(kind)
    fix = (
        f"add --observe {would[0]} or markers+{would[0]}"
        if would
        else "use an observation model that does"
    )
    raise ConfigError(
        f"scenario {spec.scenario!r}: its parameters are identifiable only if an "
        f"observation uses the model's {' or '.join(f'{n}()' for n in needs)} "
        f"(observe {spec.observe!r} does not: displacements alone do not depend "
        f"on them); {fix}"
    )


def model_inputs(
    runs: list[RunSpec],
    session: Session,
    config: CompareConfig,
    settings: Any,
    reg: Registry,
) -> tuple[list[RunSpec], list[dict[str, Any]]]:
    """The runs with their ``inputs`` digest, and what each of their models read.

    A model's ``describe()`` is everything its results depend on; a model
    that reads files (a mesh, a body description and the files it names)
    includes a digest of each file's content there (the protocol asks it to),
    so the core learns their content without knowing what they are. A run's
    digest covers the models of its mesh and of the truth mesh, on its
    scenario and on its transfer scenario.

    ``reg`` is the comparison's registry, with the scenarios the model's settings
    propose (:func:`idbench.settings.proposed_scenarios`).

    Returns
    -------
    runs
        ``runs`` with :attr:`RunSpec.inputs` set.
    entries
        One per model: ``key`` (its model key), ``role`` (``est`` or
        ``truth``), ``mesh``, ``scenario`` and ``describe``, JSON-able.
    """
    described: dict[str, dict[str, Any]] = {}
    out = []
    for spec in runs:
        transfer = reg.scenario(spec.scenario).transfer
        keys = []
        for scenario in (spec.scenario, transfer) if transfer else (spec.scenario,):
            pairs = [(spec.mesh, "est"), (spec.setup.truth_mesh, "truth")]
            for mesh, role in pairs[: 1 if spec.setup.data else 2]:
                key = spec.model_key(mesh, scenario, role)
                if key not in described:
                    build = functools.partial(session.model, spec, mesh, scenario, role)
                    model = _build(reg, config, mesh, settings, build)
                    desc = json.loads(json.dumps(model.describe(), default=str))
                    described[key] = {
                        "key": key, "role": role, "mesh": mesh, "scenario": scenario,
                        "describe": desc,
                    }  # fmt: skip
                keys.append(key)
        digest = stable_hash([described[k]["describe"] for k in keys])
        out.append(dataclasses.replace(spec, inputs=digest))
    return out, list(described.values())


def _guess_solves(reg: Registry, spec: RunSpec, n_state: int, p: int) -> int:
    """The estimator's own guess of a run's forward solves, else 2 a step.

    A plugin that cannot say (or fails, or exits) is planned with the default;
    the run itself will fail and say why.
    """
    steps = spec.setup.steps
    try:
        est = reg.estimator(spec.estimator)(**dict(spec.settings))
        guess = getattr(est, "estimate_solves", None)
        return int(guess(n_state, p, steps)) if guess else 2 * steps
    except (Exception, SystemExit) as exc:
        log.warning("estimator %r cannot estimate its cost: %r", spec.estimator, exc)
        return 2 * steps


def runs_of(config: CompareConfig, registry: Registry | None = None) -> list[RunSpec]:
    """The runs of ``config``, resolved and validated (see :func:`plan`)."""
    return plan(config, Session(registry or build_registry())).runs


def _build(
    reg: Registry,
    config: CompareConfig,
    mesh: str,
    settings: Any,
    build: Callable[[], ForwardModel] | None = None,
) -> ForwardModel:
    """Build a model of ``mesh``; a failure is one :class:`ConfigError` line."""
    assert config.model and config.scenarios
    if build is None:

        def build() -> ForwardModel:
            spec = ModelSpec(
                mesh=mesh,
                scenario=reg.scenario(config.scenarios[0]),  # type: ignore[index]
                n_steps=config.steps,
                markers=config.obs_points[0],
                settings=settings,
            )
            return reg.model(config.model)(spec)  # type: ignore[no-any-return,arg-type]

    try:
        return build()
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


def _check_estimator_settings(
    reg: Registry, name: str, settings: dict[str, Any]
) -> None:
    _known("estimator (in settings)", [name], reg.estimators, reg)
    try:
        build_settings(reg.estimator(name), settings, f"estimator {name!r}")
    except ConfigError:
        raise
    except Exception as exc:  # a plugin's own bug, still one clean line
        raise ConfigError(
            f"estimator {name!r} (plugin {reg.estimators[name].plugin!r}) "
            f"raised {type(exc).__name__}: {exc}"
        ) from None


def _check_posterior(config: CompareConfig, p: int) -> None:
    """Posterior settings that exist, are valid and whose budget can be met."""
    given = config.posterior_settings
    settings = build_settings(PosteriorSettings, given, "posterior")
    if config.posterior:
        try:
            check_budget(settings, p, config.steps)
        except ValueError as exc:
            raise ConfigError(f"posterior: {exc}") from None


def _check_calibration(config: CompareConfig, reg: Registry) -> None:
    """Calibration settings that exist, are valid and name known scenarios."""
    given = dict(config.calibration)
    scenarios = given.pop("scenarios", ())
    given.pop("mesh", None)
    build_settings(CalibrationSettings, given, "calibration")
    names = [scenarios] if isinstance(scenarios, str) else list(scenarios)
    _known("scenario (in calibration)", names, reg.scenarios, reg)


def _check_corrected(runs: list[RunSpec], config: CompareConfig) -> None:
    """Refuse a correction the runs cannot use.

    The approximation-error correction (:mod:`idbench.discrepancy`) is calibrated
    on the markers and the shape grid: an observation model other than plain
    markers would see the uncorrected model (or a marker-sized covariance), and
    a recording has no truth mesh to take the calibration mesh from.
    """
    for spec in runs:
        if dict(spec.settings).get("correction", "none") == "none":
            continue
        if spec.observed_otherwise():
            raise ConfigError(
                f"estimator {spec.estimator!r}: correction = "
                f"{dict(spec.settings)['correction']!r} needs observe = 'markers', "
                f"got {spec.observe!r}; the calibration covers markers only"
            )
        if config.data is not None and not config.calibration.get("mesh"):
            raise ConfigError(
                f"estimator {spec.estimator!r}: a correction on a recording needs "
                "a calibration mesh (--calibration-mesh): a recording has no truth mesh"
            )


def _known(kind: str, names: Any, table: dict[str, Any], reg: Registry) -> None:
    for name in names:
        if name not in table:
            allowed = ", ".join(sorted(table)) or "none registered"
            raise ConfigError(
                f"unknown {kind} {name!r}{suggest(name, table)}; allowed: {allowed}"
                f"{reg.broken()}"
            )


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
    return settings


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
        default that is refused (:class:`~idbench.lock.FolderBusy`, naming
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
            **manifest(config),
            "execution": execution,
            "plugins": the_plan.plugins,
            "inputs": the_plan.inputs,
        },
        wait=wait,
    ) as store:
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
            tick=getattr(progress, "tick", None),
        )
    order = [r.run_id for r in the_plan.runs]
    try:
        for row, traces in results:
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

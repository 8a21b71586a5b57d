"""The door: a comparison's config checked and turned into a :class:`Plan`.

Every name, value, file and combination of a :class:`~idbench.plan.config.
CompareConfig` is validated here, once, before any run starts: unknown plugins
and settings, meshes that cannot be built, a truth mesh that is not finer, a
prior outside the bounds, observation models a model cannot serve, a recording
that does not fit. What comes out is a :class:`Plan` whose runs the executors,
sessions and the harness trust without checking again.

:func:`plan` builds models to check them through a :class:`PlanSession`, a small
protocol that the run room's session satisfies (the plan never imports it).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from idbench.calibrate.design import CalibrationSettings
from idbench.core.capabilities import (
    bounds_of,
    estimate_solves_of,
    n_nodes_of,
)
from idbench.core.interfaces import ConfigError, ForwardModel, ModelSpec
from idbench.core.settings import (
    build_settings,
    execution_items,
    model_settings,
    proposed_scenarios,
    settings_identity,
    settings_items,
    suggest,
    true_values,
)
from idbench.estimate.posterior import PosteriorSettings, check_budget
from idbench.observe import kinds
from idbench.observe.registration import RegistrationError
from idbench.observe.surface import surface_of
from idbench.plan.config import CompareConfig
from idbench.plan.observations import check_markers, check_observed, resolve
from idbench.plan.runspec import RunSpec, Setup, expand
from idbench.plan.validity import check_prior, check_truth_mesh
from idbench.registry.registry import Registry, used_plugins
from idbench.store import recording, registered
from idbench.store.files import stable_hash
from idbench.store.recording import REST

log = logging.getLogger(__name__)


class PlanSession(Protocol):
    """What :func:`plan` needs of a session: its registry and its models.

    :class:`idbench.run.session.Session` satisfies it.
    """

    registry: Registry

    def model(
        self, spec: RunSpec, mesh: str, scenario: str | None = None, role: str = "est"
    ) -> ForwardModel:
        """The model of ``spec`` on ``mesh`` (built once, then shared)."""

    def observation_model(self, spec: RunSpec) -> Any:
        """The observation model of ``spec``."""


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
    skipped
        Run ids whose estimator says it will not run them (it guesses 0
        solves: e.g. the full UKF over its solve budget).
    guesses
        Per run id, the estimator's guess of its forward solves.
    """

    config: CompareConfig
    runs: list[RunSpec]
    nodes: dict[str, int]
    solves: int
    work: dict[str, float] = field(default_factory=dict)
    inputs: list[dict[str, Any]] = field(default_factory=list)
    plugins: dict[str, str] = field(default_factory=dict)
    skipped: list[str] = field(default_factory=list)
    guesses: dict[str, int] = field(default_factory=dict)


def plan(config: CompareConfig, session: PlanSession) -> Plan:
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
        config, rec = configure(config)
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
    if config.registration == "with-model" and (rec is None or rec.frame != "camera"):
        raise ConfigError(
            "registration 'with-model' refines the pose of a recording in the "
            "camera's frame; give one with --data (its manifest's frame = "
            '"camera"), or leave registration out'
        )
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
            else recording.true_values(rec, probe.parameters)
        ),
        prior=(float(config.prior[0]), float(config.prior[1])),  # type: ignore[index]
        reference=config.reference,  # type: ignore[arg-type]
        data=() if rec is None else _data(rec, config),
    )
    runs = expand(config, setup)
    nodes: dict[str, int] = {}
    models: dict[str, ForwardModel] = {}
    for mesh in (*config.meshes, *([config.truth_mesh] if rec is None else [])):
        role = "truth" if mesh == config.truth_mesh else "est"
        build = functools.partial(session.model, runs[0], mesh, role=role)
        models[mesh] = model = _build(reg, config, mesh, settings, build)
        nodes[mesh] = int(n_nodes_of(model) or 0)
    check_markers(config, models)
    for mesh in config.meshes if rec is None else ():
        truth = models[config.truth_mesh]
        check_truth_mesh(truth, config.truth_mesh, models[mesh], mesh)
    if rec is not None:
        bounds = bounds_of(models[config.meshes[0]])
        seen = [_in_body_frame(rec, models[mesh], mesh) for mesh in config.meshes]
        recording.check_body(seen[0], bounds, loads)
        obs = kinds.build(rec.observe, rec.observe_settings, reg)
        recording.check_frames(rec, obs)
    if config.observe != ("markers",) or config.observe_settings:
        built = list(models.values())
        runs = expand(config, setup, resolve(config, reg, built))
    _check_corrected(runs, config)
    _check_calibration_meshes(runs, config, reg, settings, models)
    runs, inputs = model_inputs(runs, session, config, settings, reg)
    solves, work, skipped, guesses = 0, {}, [], {}
    for spec in runs:
        model = session.model(spec, spec.mesh)
        check_observed(spec, model, session)
        n_state = model.reset().size
        guess = _guess_solves(reg, spec, n_state, model.parameters.p)
        work[spec.run_id] = float(guess) * n_state
        guesses[spec.run_id] = guess
        solves += guess
        if guess == 0:
            skipped.append(spec.run_id)
    transfers = [reg.scenario(n).transfer for n in config.scenarios]
    scenarios = {*config.scenarios, *transfers}
    plugins = used_plugins(
        reg,
        ("models", [config.model]),
        ("estimators", [*(config.estimators or ()), config.reference or ""]),
        ("scenarios", sorted(n for n in scenarios if n)),
    )
    return Plan(
        config, runs, nodes, solves, work, inputs, plugins, skipped, guesses
    )


TRUTH_MESH = "recording"
"""The truth mesh name of a comparison on a recording (there is none)."""


def configure(config: CompareConfig) -> tuple[CompareConfig, recording.Recording]:
    """``config`` with what its recording (``config.data``) fixes, and the recording.

    The recording sets the model, the scenario (its load), the steps, the
    observation model and its settings, the markers and their noise, and the
    true values it knows (others NaN); the model options are the recording's,
    to which ``config`` may add others (execution settings such as a solver).
    The truth mesh is :data:`TRUTH_MESH`.

    Raises
    ------
    RecordingError
        A setting the recording fixes given again with another value (another
        model, body, load, steps, observation, markers, points or noise): one
        line naming both values.
    """
    assert config.data, "a config with data"
    rec = recording.read(config.data)
    where = f"recording {str(rec.path)!r}"
    defaults = CompareConfig()
    fixed = {
        "model": (config.model, None, rec.model),
        "scenarios": (config.scenarios, None, (rec.scenario,)),
        "steps": (config.steps, defaults.steps, rec.steps),
        "observe": (config.observe, defaults.observe, (rec.observe,)),
        "obs_points": (config.obs_points, defaults.obs_points, (rec.markers,)),
        "noise": (config.noise, defaults.noise, (rec.noise,)),
    }
    for name, (given, default, recorded) in fixed.items():
        if given != default and given != recorded:
            raise recording.RecordingError(
                f"{where} fixes {name} = {_shown(recorded)}; got {_shown(given)} "
                "(leave it out: a recording's data cannot change)"
            )
    given_settings = config.model_settings.get(rec.model, {})
    for key, value in given_settings.items():
        if key in rec.model_settings and not _same(value, rec.model_settings[key]):
            raise recording.RecordingError(
                f"{where} is of {key} = {rec.model_settings[key]!r}; got {key} = "
                f"{value!r} (a recording is for the model options it was made with)"
            )
    for block, table in config.observe_settings.items():
        for key, value in table.items():
            recorded = rec.observe_settings.get(block, {}).get(key, value)
            if recorded != value:
                raise recording.RecordingError(
                    f"{where} fixes [observe.{block}] {key} = {recorded!r}; got "
                    f"{value!r}"
                )
    out = dataclasses.replace(
        config,
        model=rec.model,
        model_settings={
            **config.model_settings,
            rec.model: {**given_settings, **rec.model_settings},
        },
        scenarios=(rec.scenario,),
        steps=rec.steps,
        truth_mesh=TRUTH_MESH,
        observe=(rec.observe,),
        observe_settings=rec.observe_settings,
        obs_points=(rec.markers,),
        noise=(rec.noise,),
        obs_every=tuple(k for k in config.obs_every if k <= rec.steps) or (1,),
        true={},
    )
    return out, rec


def _data(rec: recording.Recording, config: CompareConfig) -> tuple[str, ...]:
    """The setup's ``data``: the recording's folder and digest, and how it is posed."""
    posed = (config.registration,) if config.registration == "with-model" else ()
    return (str(rec.path), rec.digest, *posed)


def _in_body_frame(
    rec: recording.Recording, model: ForwardModel, mesh: str
) -> recording.Recording:
    """``rec`` moved into ``model``'s frame (a camera's clouds registered).

    Raises
    ------
    ConfigError
        The rest cloud does not register to the mesh's surface (one line).
    """
    if rec.frame != "camera":
        return rec
    try:
        return registered.to_body(rec, *surface_of(model, model.reset()))[0]
    except (RegistrationError, ValueError) as exc:
        raise ConfigError(
            f"recording {str(rec.path)!r}: its rest cloud ({REST}) does not "
            f"register to mesh {mesh!r}: {exc}"
        ) from None


def _shown(value: Any) -> str:
    """A fixed setting as the command line writes it (a list comma-separated)."""
    if isinstance(value, tuple):
        return ",".join(str(v) for v in value)
    return repr(value)


def _same(given: Any, recorded: Any) -> bool:
    """Whether a model option equals the recording's (a path: the same file)."""
    if given == recorded:
        return True
    if isinstance(given, str) and isinstance(recorded, str):
        a, b = Path(given), Path(recorded)
        return a.is_file() and b.is_file() and a.resolve() == b.resolve()
    return False


def model_inputs(
    runs: list[RunSpec],
    session: PlanSession,
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
    propose (:func:`idbench.core.settings.proposed_scenarios`).

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
        guess = estimate_solves_of(est)
        return int(guess(n_state, p, steps)) if guess else 2 * steps
    except (Exception, SystemExit) as exc:
        log.warning("estimator %r cannot estimate its cost: %r", spec.estimator, exc)
        return 2 * steps


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

    A recording has no truth mesh to take the calibration mesh from. (The
    approximation-error correction of markers is calibrated offline,
    :mod:`idbench.calibrate.discrepancy`; of any other observation model on
    each run's frames, :func:`idbench.calibrate.prior_mean.linear_offsets`.)
    """
    for spec in runs:
        correction = dict(spec.settings).get("correction", "none")
        if correction == "none":
            continue
        if config.data is not None and not config.calibration.get("mesh"):
            raise ConfigError(
                f"estimator {spec.estimator!r}: a correction on a recording needs "
                "a calibration mesh (--calibration-mesh): a recording has no truth mesh"
            )


def _check_calibration_meshes(
    runs: list[RunSpec],
    config: CompareConfig,
    reg: Registry,
    settings: Any,
    models: dict[str, ForwardModel],
) -> None:
    """Refuse a calibration mesh that is not finer than a run's mesh, or another body.

    As a truth mesh is checked (:func:`~idbench.plan.validity.check_truth_mesh`),
    but the model mesh itself is refused too.

    Raises
    ------
    ConfigError
        One line naming both meshes and what differs.
    """
    pairs = {(str(dict(s.calibration)["mesh"]), s.mesh) for s in runs if s.calibration}
    for fine, mesh in sorted(pairs):
        if fine not in models:
            models[fine] = _build(reg, config, fine, settings)
        check_truth_mesh(models[fine], fine, models[mesh], mesh, role="calibration")


def _known(kind: str, names: Any, table: dict[str, Any], reg: Registry) -> None:
    for name in names:
        if name not in table:
            allowed = ", ".join(sorted(table)) or "none registered"
            raise ConfigError(
                f"unknown {kind} {name!r}{suggest(name, table)}; allowed: {allowed}"
                f"{reg.broken()}"
            )

"""Per-process memo of what runs share: models, truths, reference fits, direct runs.

A :class:`Session` belongs to one thread of one process (models keep caches
such as factorizations that two threads must not use at once). The truth is
also cached on disk (:mod:`idbench.truth`).
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

import numpy as np

from idbench.config import ConfigError, build_settings, public_settings, typed_values
from idbench.discrepancy import (
    CalibrationSettings,
    CorrectedModel,
    Discrepancy,
    calibrate,
)
from idbench.files import stable_hash
from idbench.interfaces import (
    FloatArray,
    ForwardModel,
    ModelSpec,
    Observation,
    ParameterSpec,
    Prior,
)
from idbench.plugins import Registry, build_registry
from idbench.posterior import Posterior, PosteriorSettings, reference_posterior
from idbench.runspec import RunSpec
from idbench.truth import Truth, simulate_path, simulate_truth

log = logging.getLogger(__name__)

_NO_STATES = np.empty((0, 0))


def model_settings(registry: Registry, model: str, given: dict[str, Any]) -> Any:
    """The settings object of ``model`` with ``given`` values (None: no settings).

    Raises
    ------
    ConfigError
        Naming an unknown setting (and the allowed ones) or a bad value.
    """
    entry = registry.models[model]
    cls = entry.settings
    if cls is None:
        if given:
            raise ConfigError(f"model {model!r} has no settings; got {sorted(given)}")
        return None
    what = f"model {model!r}"
    return build_settings(cls, _typed(cls, given, what), what)


def _typed(cls: type, given: dict[str, Any], what: str) -> dict[str, Any]:
    """``given`` checked against the field types, whole numbers as floats.

    So that ``nu=0`` and ``nu=0.0`` are one setting (one run id, one noise
    seed), and ``nu=abc`` is one line (:func:`idbench.config.typed_values`).
    """
    return typed_values(cls, given, what)


def estimator_arguments(cls: type, settings: Any, seed: int) -> dict[str, Any]:
    """Keyword arguments for an estimator class: its settings, plus the run's seed.

    An estimator with a ``seed`` setting (its own random draws) gets the run's
    seed unless the user set one, so seeds differ between the runs of a sweep
    and repeat with them. The seed is not added to the settings themselves:
    the run id (and resuming) stays as it was.
    """
    kwargs = dict(settings)
    try:
        seeded = "seed" in public_settings(cls)
    except TypeError:  # not a dataclass: no settings we can see
        seeded = False
    if seeded and "seed" not in kwargs:
        kwargs["seed"] = int(seed)
    return kwargs


def settings_items(settings: Any) -> tuple[tuple[str, Any], ...]:
    """Sorted (name, value) items of a settings object (empty for None).

    Its execution settings (:func:`execution_names`) are left out.
    """
    if settings is None:
        return ()
    skip = set(execution_names(settings))
    return tuple(sorted(i for i in dataclasses.asdict(settings).items()
                        if i[0] not in skip))  # fmt: skip


def execution_names(settings: Any) -> tuple[str, ...]:
    """The settings that change where or how fast work runs, not its results.

    A settings dataclass names them in a class attribute ``EXECUTION`` (a
    tuple of field names; e.g. helper processes). They reach the model but
    are left out of run ids, model keys, result rows and the check that an
    output folder holds the same comparison, so changing them resumes a
    comparison instead of starting another. A settings class that defines
    ``identity()`` must leave them out of it, and the model out of its
    ``describe()`` (both key data and caches).
    """
    return tuple(getattr(settings, "EXECUTION", ()))


def execution_items(settings: Any) -> tuple[tuple[str, Any], ...]:
    """Sorted (name, value) items of the execution settings (empty for None)."""
    if settings is None:
        return ()
    names = execution_names(settings)
    return tuple(sorted((n, getattr(settings, n)) for n in names))


def settings_identity(settings: Any) -> tuple[Any, ...]:
    """What of ``settings`` identifies the data: its ``identity()`` or all of it."""
    identity = getattr(settings, "identity", None)
    if callable(identity):
        return tuple(identity())
    return tuple([list(item) for item in settings_items(settings)])


def true_values(
    parameters: ParameterSpec, given: dict[str, float], model: str
) -> tuple[tuple[str, float], ...]:
    """The true value of every parameter: ``given``, else the model's default.

    Raises
    ------
    ConfigError
        For a name the model does not have, a value missing without a default,
        or values outside the parameter bounds.
    """
    names = parameters.names
    for name in given:
        if name not in names:
            raise ConfigError(
                f"true value for {name!r}: model {model!r} has no such parameter; "
                f"its parameters: {', '.join(names)}"
            )
    defaults = parameters.default or (None,) * len(names)
    values = []
    for name, default in zip(names, defaults, strict=True):
        value = given.get(name, default)
        if value is None:
            raise ConfigError(
                f"no true value for parameter {name!r} of model {model!r}: "
                f"give one with --true {name}=VALUE"
            )
        values.append((name, float(value)))
    if not parameters.contains(np.array([v for _, v in values])):
        raise ConfigError(
            f"true values {dict(values)} lie outside the parameter bounds "
            f"{parameters.lower}..{parameters.upper}"
        )
    return tuple(values)


class Session:
    """Per-process memo of models, truths, reference fits and direct runs."""

    def __init__(self, registry: Registry | None = None) -> None:
        self.registry = registry or build_registry()
        self._models: dict[str, ForwardModel] = {}
        self._truths: dict[str, Truth] = {}
        self._refs: dict[str, FloatArray] = {}
        self._direct: dict[str, FloatArray] = {}
        self._posteriors: dict[str, Posterior | None] = {}
        self._discrepancies: dict[str, Discrepancy] = {}

    def model(
        self, spec: RunSpec, mesh: str, scenario: str | None = None, role: str = "est"
    ) -> ForwardModel:
        """The forward model of ``mesh`` on ``scenario`` (one per role)."""
        scenario = scenario or spec.scenario
        # execution settings (not in model_key) still pick the model object: a
        # long-lived session must not serve a later sweep an earlier one's
        key = spec.model_key(mesh, scenario, role) + repr(spec.setup.execution)
        if key not in self._models:
            ms = self.model_spec(spec, mesh, scenario)
            self._models[key] = self.registry.model(spec.setup.model)(ms)
        return self._models[key]

    def model_spec(self, spec: RunSpec, mesh: str, scenario: str) -> ModelSpec:
        """What the model factory of ``spec`` gets for ``mesh`` on ``scenario``."""
        setup = spec.setup
        settings = model_settings(
            self.registry,
            setup.model,
            {**dict(setup.model_settings), **dict(setup.execution)},
        )
        return ModelSpec(
            mesh=mesh,
            scenario=self.registry.scenario(scenario),
            n_steps=setup.steps,
            markers=spec.obs_points,
            settings=settings,
        )

    def discrepancy(self, spec: RunSpec) -> Discrepancy:
        """The calibration of the run's mesh against its calibration mesh.

        Computed on first use (fine paths of its own design, never the
        truth's data) and cached on disk (:func:`idbench.discrepancy.calibrate`).

        Raises
        ------
        ConfigError
            For an uncorrected run or bad calibration settings.
        """
        if spec.calibration is None:
            raise ConfigError(f"run {spec.run_id} has no calibration settings")
        given = dict(spec.calibration)
        mesh = str(given.pop("mesh"))
        names = tuple(given.pop("scenarios"))
        key = stable_hash([spec.model_key(spec.mesh, spec.scenario, "est"),
                           list(spec.calibration), list(spec.setup.prior)])  # fmt: skip
        if key not in self._discrepancies:
            try:
                settings = CalibrationSettings(**given)
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"calibration: {exc}") from None
            model = self.model(spec, spec.mesh)
            prior = self.prior(model, spec)
            scenarios = [self.registry.scenario(n) for n in names]
            self._discrepancies[key] = calibrate(
                self.registry.model(spec.setup.model),
                self.model_spec(spec, spec.mesh, spec.scenario),
                mesh, scenarios, prior, settings,
            )  # fmt: skip
        return self._discrepancies[key]

    def corrected(self, spec: RunSpec, model: ForwardModel) -> CorrectedModel:
        """``model`` corrected by the run's calibration (a new wrapper per call).

        The covariance is weighted by the run's number of observed steps (see
        :mod:`idbench.discrepancy`).
        """
        n_obs = sum(spec.sparsity.observed(k) for k in range(1, spec.setup.steps + 1))
        return CorrectedModel(model, self.discrepancy(spec), n_obs)

    def theta_true(self, spec: RunSpec) -> FloatArray:
        """True parameters (p,), in the model's order."""
        return np.array([v for _, v in spec.setup.true], dtype=float)

    def truth(self, spec: RunSpec, scenario: str | None = None) -> Truth:
        """The truth of ``scenario`` (default: the run's), from the disk cache."""
        scenario = scenario or spec.scenario
        # the states depend on the set-up only (cached on disk), the probed
        # observations also on the markers: one Truth per truth model and
        # true values (a session may serve sweeps with other true values)
        key = spec.truth_product_key(scenario)
        if key not in self._truths:
            model = self.model(spec, spec.setup.truth_mesh, scenario, role="truth")
            self._truths[key] = simulate_truth(model, self.theta_true(spec))
        return self._truths[key]

    def observations(self, spec: RunSpec) -> list[Observation | None]:
        """The noisy, sparse observation stream of a run.

        Standard normals are drawn once per :meth:`RunSpec.noise_key` (the
        same for every estimator, mesh, noise level and spacing of a sweep),
        scaled by the run's noise sigma; the spacing only selects steps.
        """
        truth = self.truth(spec)
        seq = np.random.SeedSequence(
            [spec.seed, int(stable_hash(spec.noise_key()), 16)]
        )
        rng = np.random.default_rng(seq)
        noise = rng.standard_normal(truth.observations.shape) * spec.noise
        stream: list[Observation | None] = []
        for k in range(1, spec.setup.steps + 1):
            if spec.sparsity.observed(k):
                values = truth.observations[k - 1] + noise[k - 1]
                stream.append(Observation(values, spec.noise, k))
            else:
                stream.append(None)
        return stream

    def prior(self, model: ForwardModel, spec: RunSpec) -> Prior:
        """The run's prior, the same for every parameter."""
        mean, std = spec.setup.prior
        return Prior.broadcast(mean, std, model.parameters.p)

    def known_reference(self, spec: RunSpec) -> FloatArray | None:
        """The reference value of ``spec``'s data if this session has it."""
        return self._refs.get(spec.reference_key())

    def remember_reference(self, spec: RunSpec, value: FloatArray) -> None:
        """Seed the reference value of ``spec``'s data (fitted by another worker)."""
        self._refs[spec.reference_key()] = np.asarray(value, dtype=float)

    def shared(self) -> dict[tuple[str, str], Any]:
        """What this session computed that another process can reuse.

        The probed truths (without their states, which runs do not read),
        the reference fits and the direct runs, by (kind, key); pass them to
        another session's :meth:`adopt` (the worker pool does, so a worker
        neither probes a truth the parent prepared nor repeats what another
        worker did).
        """
        out: dict[tuple[str, str], Any] = {
            ("truth", k): dataclasses.replace(v, states=_NO_STATES)
            for k, v in self._truths.items()
        }
        out.update({("reference", k): v for k, v in self._refs.items()})
        out.update({("direct", k): v for k, v in self._direct.items()})
        return out

    def products(self, spec: RunSpec) -> set[tuple[str, str]]:
        """The keys (see :meth:`shared`) of what running ``spec`` computes if new.

        Its data's reference fit, its direct runs and probed truths (its
        scenario's and the transfer scenario's).
        """
        keys = {("reference", spec.reference_key())}
        target = self.registry.scenario(spec.scenario).transfer
        for scenario in (spec.scenario, target):
            if scenario:
                keys.add(("direct", spec.direct_key(scenario)))
                keys.add(("truth", spec.truth_product_key(scenario)))
        return keys

    def adopt(self, shared: dict[tuple[str, str], Any]) -> None:
        """Take over what another session computed (see :meth:`shared`)."""
        for (kind, key), value in shared.items():
            if kind == "truth":
                self._truths.setdefault(key, value)
            else:
                table = self._refs if kind == "reference" else self._direct
                table.setdefault(key, np.asarray(value, dtype=float))

    def reference(self, spec: RunSpec) -> FloatArray:
        """The reference estimator fitted on the run's own data."""
        key = spec.reference_key()
        if key not in self._refs:
            model = self.model(spec, spec.mesh, role="ref")
            p = model.parameters.p
            try:
                cls = self.registry.estimator(spec.setup.reference)
                est = cls(**estimator_arguments(cls, {}, spec.seed))
                est.start(model, self.prior(model, spec))
                e = None
                for k, obs in enumerate(self.observations(spec), start=1):
                    e = est.update(k, obs)
                self._refs[key] = (
                    np.asarray(e.mean, dtype=float) if e else np.full(p, np.nan)
                )
            except Exception as exc:
                log.warning("reference fit failed for %s: %s", spec.mesh, exc)
                self._refs[key] = np.full(p, np.nan)
        return self._refs[key]

    def posterior(self, spec: RunSpec) -> Posterior | None:
        """The reference posterior of the run's data on its model mesh (cached).

        Keyed like the reference fit (and by the posterior settings), so every
        estimator on the same data and mesh shares one. None if the run asks
        for none (``spec.posterior`` is None) or it could not be computed (the
        budget ran out, the model could not be solved anywhere): logged.
        """
        if spec.posterior is None:
            return None
        key = stable_hash([spec.reference_key(), list(spec.posterior)])
        if key not in self._posteriors:
            model = self.model(spec, spec.mesh, role="posterior")
            settings = PosteriorSettings(**dict(spec.posterior))
            try:
                post: Posterior | None = reference_posterior(
                    model, self.prior(model, spec), self.observations(spec), settings
                )
            except ValueError as exc:
                log.warning("reference posterior failed for %s: %s", spec.mesh, exc)
                post = None
            self._posteriors[key] = post
        return self._posteriors[key]

    def direct(self, spec: RunSpec, scenario: str | None = None) -> FloatArray:
        """Shape-error point displacements (K, G, d) of the model run with the truth."""
        scenario = scenario or spec.scenario
        key = spec.direct_key(scenario)
        if key not in self._direct:
            model = self.model(spec, spec.mesh, scenario, role="metrics")
            states = simulate_path(model, self.theta_true(spec))
            self._direct[key] = np.array([model.grid(s) for s in states])
        return self._direct[key]

"""Per-process memo of what runs share: models, truths, reference fits, direct runs.

A :class:`Session` belongs to one thread of one process (models keep caches
such as factorizations that two threads must not use at once). The truth is
also cached on disk (:mod:`idbench.truth.simulate`).
"""

from __future__ import annotations

import dataclasses
import logging
import typing
from typing import Any

import numpy as np

from idbench.calibrate.corrected import CorrectedModel
from idbench.calibrate.design import CalibrationSettings
from idbench.calibrate.discrepancy import Discrepancy
from idbench.calibrate.fit import fit_discrepancy
from idbench.calibrate.pose import Refinement, posed
from idbench.calibrate.prior_mean import linear_offsets, prior_mean_offsets
from idbench.core.interfaces import (
    ConfigError,
    FloatArray,
    ForwardModel,
    ModelSpec,
    Observation,
    Prior,
)
from idbench.core.scenario import Scenario
from idbench.core.settings import (
    estimator_arguments,
    model_settings,
    proposed_scenarios,
)
from idbench.estimate.posterior import Posterior, PosteriorSettings, reference_posterior
from idbench.estimate.transforms import LogTransform
from idbench.observe import kinds
from idbench.observe.observed_model import ObservedModel
from idbench.observe.offsets import Offsets
from idbench.observe.registration import Registration
from idbench.observe.surface import surface_of
from idbench.plan.runspec import RunSpec
from idbench.registry.registry import Registry, build_registry
from idbench.run.isolation import changes, fingerprint, private_copy
from idbench.store import recording, registered
from idbench.store.files import stable_hash
from idbench.truth.simulate import Truth, simulate_path, simulate_truth

log = logging.getLogger(__name__)

_NO_STATES = np.empty((0, 0))


class Session:
    """Per-process memo of models, truths, reference fits and direct runs."""

    def __init__(self, registry: Registry | None = None) -> None:
        self.registry = registry or build_registry()
        self._models: dict[str, ForwardModel] = {}
        self._prints: dict[int, dict[str, str]] = {}  # by id of a master model
        self._truths: dict[str, Truth] = {}
        self._refs: dict[str, FloatArray] = {}
        self._direct: dict[str, FloatArray] = {}
        self._posteriors: dict[str, Posterior | None] = {}
        self._sensed: dict[str, list[dict[str, FloatArray]]] = {}
        self._frames: dict[str, list[kinds.Frame]] = {}
        self._own: dict[Any, dict[str, Scenario]] = {}
        self._discrepancies: dict[str, Discrepancy] = {}
        self._offsets: dict[str, Offsets] = {}
        self._registered: dict[tuple[str, ...], tuple[Any, Registration]] = {}
        self._refined: dict[tuple[str, ...], Refinement] = {}

    def scenario(self, spec: RunSpec, name: str) -> Scenario:
        """The scenario ``name`` of ``spec``'s comparison.

        The model settings' own scenarios first (``proposed_scenarios()``,
        e.g. a body file's manipulations), else the registered one: a worker
        that builds its registry from the installed plugins finds them too.
        """
        setup = spec.setup
        key = (setup.model, setup.model_settings)
        own = self._own.get(key)
        if own is None:
            settings = model_settings(
                self.registry, setup.model, dict(setup.model_settings)
            )
            found = proposed_scenarios(settings, setup.model)
            own = self._own[key] = {sc.name: sc for sc in found}
        return own[name] if name in own else self.registry.scenario(name)

    def model(
        self, spec: RunSpec, mesh: str, scenario: str | None = None, role: str = "est"
    ) -> ForwardModel:
        """The forward model of ``mesh`` on ``scenario`` (one per role).

        Built once and kept (the *master*); code that hands a model to a
        plugin gives it :meth:`lend`'s copy instead.
        """
        scenario = scenario or spec.scenario
        # execution settings (not in model_key) still pick the model object: a
        # long-lived session must not serve a later sweep an earlier one's
        key = spec.model_key(mesh, scenario, role) + repr(spec.setup.execution)
        if key not in self._models:
            ms = self.model_spec(spec, mesh, scenario)
            model = self.registry.model(spec.setup.model)(ms)
            self._prints[id(model)] = fingerprint(model)
            self._models[key] = model
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
            scenario=self.scenario(spec, scenario),
            n_steps=setup.steps,
            markers=spec.obs_points,
            settings=settings,
        )

    def lend(
        self, spec: RunSpec, mesh: str, scenario: str | None = None, role: str = "est"
    ) -> tuple[ForwardModel, ForwardModel]:
        """The master of :meth:`model` and a private copy of it for one run.

        See :mod:`idbench.run.isolation`; give both back to :meth:`returned`.
        """
        master = self.model(spec, mesh, scenario, role)
        return master, private_copy(master)

    def returned(self, master: ForwardModel, copy: ForwardModel) -> list[str]:
        """What a run changed in its copy or in the master (empty: nothing).

        Compared with the master's fingerprint when it was built
        (:func:`idbench.run.isolation.fingerprint`). A changed master is
        discarded: the next run gets one built anew.
        """
        before = self._prints.get(id(master))
        if before is None:  # discarded already
            return []
        changed = set(changes(before, fingerprint(copy)))
        in_master = changes(before, fingerprint(master))
        if in_master:
            changed.update(in_master)
            self._prints.pop(id(master))
            for key in [k for k, m in self._models.items() if m is master]:
                del self._models[key]
            log.warning("a run changed a shared model (%s): built anew", in_master)
        return sorted(changed)

    def discrepancy(self, spec: RunSpec) -> Discrepancy:
        """The calibration of the run's mesh against its calibration mesh.

        Computed on first use (fine paths of its own design, never the
        truth's data) and cached on disk
        (:func:`idbench.calibrate.fit.fit_discrepancy`).

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
            scenarios = [self.scenario(spec, n) for n in names]
            self._discrepancies[key] = fit_discrepancy(
                self.registry.model(spec.setup.model),
                self.model_spec(spec, spec.mesh, spec.scenario),
                mesh, scenarios, prior, settings,
            )  # fmt: skip
        return self._discrepancies[key]

    def corrected(self, spec: RunSpec, model: ForwardModel) -> CorrectedModel:
        """``model`` corrected by the run's calibration (a new wrapper per call).

        The covariance is weighted by the run's number of observed steps (see
        :mod:`idbench.calibrate.discrepancy`).
        """
        return CorrectedModel(model, self.discrepancy(spec), _observed_steps(spec))

    def theta_true(self, spec: RunSpec) -> FloatArray:
        """True parameters (p,), in the model's order."""
        return np.array([v for _, v in spec.setup.true], dtype=float)

    def truth(self, spec: RunSpec, scenario: str | None = None) -> Truth:
        """The truth of ``scenario`` (default: the run's), from the disk cache."""
        scenario = scenario or spec.scenario
        if spec.setup.data:
            return self._recorded_truth(spec)
        # the states depend on the set-up only (cached on disk), the probed
        # observations also on the markers: one Truth per truth model and
        # true values (a session may serve sweeps with other true values)
        key = spec.truth_product_key(scenario)
        if key not in self._truths:
            model = self.model(spec, spec.setup.truth_mesh, scenario, role="truth")
            self._truths[key] = simulate_truth(model, self.theta_true(spec))
        return self._truths[key]

    def _recorded_truth(self, spec: RunSpec) -> Truth:
        """What a recording holds out, as a truth for ``spec``'s model mesh.

        Held-out markers as the observations (NaN without), held-out targets
        as the targets, held-out points as ``held_points``; no states,
        probes or nodes; the shape-error grid NaN (in the metrics model's
        shape: there is no truth field to compare).
        """
        key = spec.truth_product_key(spec.scenario)
        if key not in self._truths:
            rec = self.recorded(spec)
            model = self.model(spec, spec.mesh, role="metrics")
            u0 = model.reset()
            steps = spec.setup.steps
            grid = np.asarray(model.grid(u0)).shape
            markers = rec.held_out.get("markers")
            if markers is None:
                markers = np.full((steps, np.asarray(model.observe(u0)).size), np.nan)
            self._truths[key] = Truth(
                states=np.empty((steps, 0)),
                observations=np.asarray(markers, dtype=float),
                grid=np.full((steps, *grid), np.nan),
                probes={},
                targets=rec.held_out.get("targets"),
                held_points=rec.held_out.get("points"),
            )
        return self._truths[key]

    def recorded(self, spec: RunSpec) -> recording.Recording:
        """The run's recording (``spec.setup.data``), as planned.

        Raises
        ------
        ConfigError
            If its content changed since the comparison was planned.
        """
        rec = self._planned(spec)
        if rec.frame != "camera":
            return rec
        return self._to_body(spec, rec)[0]

    def _planned(self, spec: RunSpec) -> recording.Recording:
        """The run's recording as read from disk, checked against the plan's digest."""
        path, digest = spec.setup.data[:2]
        rec = recording.read(path)
        if rec.digest != digest:
            raise ConfigError(f"recording {path!r} changed since it was planned")
        return rec

    def registration(self, spec: RunSpec) -> Registration | None:
        """How the run's recording was moved into its model's frame (None: not)."""
        if not spec.setup.data:
            return None
        rec = self._planned(spec)
        return self._to_body(spec, rec)[1] if rec.frame == "camera" else None

    def _to_body(
        self, spec: RunSpec, rec: recording.Recording
    ) -> tuple[recording.Recording, Registration]:
        """``rec`` registered to the rest surface of the run's model mesh (cached)."""
        key = (rec.digest, spec.mesh, *spec.setup.data[2:])
        if key not in self._registered:
            model = self.model(spec, spec.mesh)
            surface = surface_of(model, model.reset())
            self._registered[key] = registered.to_body(rec, *surface)
            if "with-model" in spec.setup.data[2:]:  # refined with the model
                prior = self.prior(model, spec)
                moved, found = posed(rec, *self._registered[key], model, prior)
                self._registered[key], self._refined[key] = (moved, found.fit), found
        return self._registered[key]

    def refinement(self, spec: RunSpec) -> Refinement | None:
        """How the model refined the run's rigid pose (None: it did not)."""
        if "with-model" not in spec.setup.data[2:]:
            return None
        key = (spec.setup.data[1], spec.mesh, *spec.setup.data[2:])
        if key not in self._refined:  # the recording read once, as planned
            self._to_body(spec, self._planned(spec))
        return self._refined[key]

    def observations(self, spec: RunSpec) -> list[Observation | None]:
        """The noisy, sparse observation stream of a run.

        Plain markers: standard normals are drawn once per
        :meth:`RunSpec.noise_key` (the same for every estimator, mesh, noise
        level and spacing of a sweep), scaled by the run's noise sigma; the
        spacing only selects steps. Another observation model: its frames
        (:meth:`frames`) made into observations of the observed steps (a
        frame whose values are all NaN, every marker occluded, is none).
        """
        if spec.observed_otherwise() or spec.setup.data:
            obs = self.observation_model(spec)
            stream: list[Observation | None] = []
            for k, frame in enumerate(self.frames(spec), start=1):
                if not spec.sparsity.observed(k):
                    stream.append(None)
                    continue
                values = np.asarray(obs.values(frame), dtype=float)
                if _occluded(values):  # every value occluded (NaN): unobserved
                    stream.append(None)
                    continue
                std = obs.noise_std(frame, spec.noise)
                stream.append(Observation(values, _noise(std), k))
            return stream
        truth = self.truth(spec)
        seq = np.random.SeedSequence(
            [spec.seed, int(stable_hash(spec.noise_key()), 16)]
        )
        rng = np.random.default_rng(seq)
        noise = rng.standard_normal(truth.observations.shape) * spec.noise
        stream = []
        for k in range(1, spec.setup.steps + 1):
            if spec.sparsity.observed(k):
                values = truth.observations[k - 1] + noise[k - 1]
                stream.append(Observation(values, spec.noise, k))
            else:
                stream.append(None)
        return stream

    def observation_model(self, spec: RunSpec) -> Any:
        """The run's :class:`~idbench.core.observation_model.ObservationModel`."""
        return kinds.from_items(spec.observe, spec.observe_settings, self.registry)

    def frames(self, spec: RunSpec) -> list[kinds.Frame]:
        """The run's frame of every step 1..K (simulated from the truth).

        Read from the recording instead where the run has one
        (``spec.setup.data``, :mod:`idbench.store.recording`).

        Each block senses the truth once per (truth, block settings but its
        noise) (:meth:`sensed`), then measures with its own generator, seeded
        by the run's :meth:`RunSpec.noise_key` and the block's identity
        (common random numbers across estimators and meshes; the markers'
        generator is today's).
        """
        if spec.setup.data:  # a recording's frames, instead of the truth's
            return self.recorded(spec).frames
        key = stable_hash([spec.data_key(), list(spec.observe_settings)])
        if key not in self._frames:
            obs = self.observation_model(spec)
            named = []
            for name, block in kinds.leaves(obs):
                clean = self.sensed(spec, block)
                ident = block.identity()
                noise_key = spec.noise_key() + ([ident] if ident else [])
                seq = np.random.SeedSequence(
                    [spec.seed, int(stable_hash(noise_key), 16)]
                )
                data = block.measure(clean, np.random.default_rng(seq), spec.noise)
                named.append((name, data))
            frames = []
            for k in range(1, spec.setup.steps + 1):
                if len(named) == 1:
                    data_k = dict(named[0][1][k - 1])
                else:
                    data_k = kinds.Combined.merge([(n, d[k - 1]) for n, d in named])
                frames.append(kinds.Frame(k, data_k))
            self._frames[key] = frames
        return self._frames[key]

    def sensed(self, spec: RunSpec, block: Any) -> list[dict[str, FloatArray]]:
        """The noise-free readings (K,) of ``block`` on the run's truth (cached).

        Markers read the probed truth; other blocks sense its states (read
        again from the disk cache where this session adopted the truth
        without them).
        """
        if isinstance(block, kinds.Markers):
            truth = self.truth(spec)
            return [{"markers": row} for row in truth.observations]
        key = self._sensed_key(spec, block)
        if key not in self._sensed:
            model = self.model(spec, spec.setup.truth_mesh, role="truth")
            truth = self.truth(spec)
            states = truth.states
            if states.shape[0] != spec.setup.steps:
                states = simulate_truth(model, self.theta_true(spec)).states
            theta = self.theta_true(spec)
            self._sensed[key] = [
                block.sense(model, theta, k, states[k - 1])
                for k in range(1, spec.setup.steps + 1)
            ]
        return self._sensed[key]

    def _sensed_key(self, spec: RunSpec, block: Any) -> str:
        return stable_hash([spec.truth_product_key(spec.scenario), block.identity()])

    def estimator_model(self, spec: RunSpec, model: ForwardModel) -> ForwardModel:
        """``model`` as the run's estimator sees it: h(x) of its observation model.

        Plain markers: ``model`` itself (bitwise today's path).
        """
        if not spec.observed_otherwise():
            return model
        wrapped: Any = ObservedModel(
            model, self.observation_model(spec), self.frames(spec)
        )
        return typing.cast(ForwardModel, wrapped)

    def mean_corrected(
        self, spec: RunSpec, seen: ForwardModel, linear: bool = False
    ) -> ForwardModel:
        """The run's estimator model with the approximation error of its frames.

        ``correction = "prior-mean"`` (:mod:`idbench.calibrate.prior_mean`):
        step k's h(x) plus mu_k, the calibration mesh's prediction minus the
        run's mesh's at the prior mean (a path on each, kept per data, mesh
        and prior); ``linear`` (the approximation-error correction off the
        markers): as a line in ln theta with a covariance, weighted by the
        observed steps (:func:`~idbench.calibrate.prior_mean.linear_offsets`).
        """
        if spec.calibration is None:
            raise ConfigError(f"run {spec.run_id} has no calibration settings")
        fine_mesh = str(dict(spec.calibration)["mesh"])
        key = stable_hash(
            [spec.reference_key(), fine_mesh, list(spec.setup.prior), linear]
        )
        wrapped = seen if isinstance(seen, ObservedModel) else ObservedModel(
            seen, self.observation_model(spec), self.frames(spec)
        )  # plain markers: their h is the model's observe
        if key not in self._offsets:
            coarse = self.model(spec, spec.mesh, role="calibration")
            fine = self.model(spec, fine_mesh, role="calibration")
            observe, frames = self.observation_model(spec), self.frames(spec)
            pair = (ObservedModel(fine, observe, frames),
                    ObservedModel(coarse, observe, frames))  # fmt: skip
            prior = self.prior(coarse, spec)
            theta0 = np.asarray(prior.mean, dtype=float)
            if linear:
                cov = LogTransform().prior(theta0, np.asarray(prior.std, float))[1]
                found = linear_offsets(*pair, theta0, np.sqrt(np.diag(cov)))
                n_obs = _observed_steps(spec)
                self._offsets[key] = dataclasses.replace(
                    found, covs=[n_obs * c for c in found.covs or []]
                )
            else:
                self._offsets[key] = Offsets(prior_mean_offsets(*pair, theta0))
        wrapped.offsets = self._offsets[key]
        return typing.cast(ForwardModel, wrapped)

    def prior(self, model: ForwardModel, spec: RunSpec) -> Prior:
        """The run's prior: the comparison's, but for parameters with their own.

        (:attr:`idbench.ParameterSpec.priors`, a model's.)
        """
        mean, std = spec.setup.prior
        return model.parameters.prior(mean, std)

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
        out.update({("sensed", k): v for k, v in self._sensed.items()})
        out.update({("direct", k): v for k, v in self._direct.items()})
        return out

    def products(self, spec: RunSpec) -> set[tuple[str, str]]:
        """The keys (see :meth:`shared`) of what running ``spec`` computes if new.

        Its data's reference fit, its direct runs and probed truths (its
        scenario's and the transfer scenario's).
        """
        keys = {("reference", spec.reference_key())}
        target = self.scenario(spec, spec.scenario).transfer
        for scenario in (spec.scenario, target):
            if scenario:
                keys.add(("direct", spec.direct_key(scenario)))
                keys.add(("truth", spec.truth_product_key(scenario)))
        if spec.observed_otherwise():
            for _, block in kinds.leaves(self.observation_model(spec)):
                if not isinstance(block, kinds.Markers):
                    keys.add(("sensed", self._sensed_key(spec, block)))
        return keys

    def adopt(self, shared: dict[tuple[str, str], Any]) -> None:
        """Take over what another session computed (see :meth:`shared`)."""
        for (kind, key), value in shared.items():
            if kind == "truth":
                self._truths.setdefault(key, value)
            elif kind == "sensed":
                self._sensed.setdefault(key, value)
            else:
                table = self._refs if kind == "reference" else self._direct
                table.setdefault(key, np.asarray(value, dtype=float))

    def reference(self, spec: RunSpec) -> FloatArray:
        """The reference estimator fitted on the run's own data."""
        key = spec.reference_key()
        if key not in self._refs:
            master, model = self.lend(spec, spec.mesh, role="ref")
            p = master.parameters.p
            try:
                cls = self.registry.estimator(spec.setup.reference)
                est = cls(**estimator_arguments(cls, {}, spec.seed))
                est.start(self.estimator_model(spec, model), self.prior(master, spec))
                e = None
                for k, obs in enumerate(self.observations(spec), start=1):
                    e = est.update(k, obs)
                self._refs[key] = (
                    np.asarray(e.mean, dtype=float) if e else np.full(p, np.nan)
                )
            except Exception as exc:
                log.warning("reference fit failed for %s: %s", spec.mesh, exc)
                self._refs[key] = np.full(p, np.nan)
            changed = self.returned(master, model)
            if changed:
                log.warning(
                    "reference fit for %s: %r changed the model it was given (%s)",
                    spec.mesh, spec.setup.reference, ", ".join(changed),
                )  # fmt: skip
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
                    self.estimator_model(spec, model), self.prior(model, spec),
                    self.observations(spec), settings,
                )  # fmt: skip
            except ValueError as exc:
                log.warning("reference posterior failed for %s: %s", spec.mesh, exc)
                post = None
            self._posteriors[key] = post
        return self._posteriors[key]

    def direct(self, spec: RunSpec, scenario: str | None = None) -> FloatArray:
        """Shape-error point displacements (K, G, d) of the model run with the truth."""
        scenario = scenario or spec.scenario
        key = spec.direct_key(scenario)
        if spec.setup.data and key not in self._direct:  # no true values: NaN
            return np.full_like(self.truth(spec).grid, np.nan)
        if key not in self._direct:
            model = self.model(spec, spec.mesh, scenario, role="metrics")
            states = simulate_path(model, self.theta_true(spec))
            self._direct[key] = np.array([model.grid(s) for s in states])
        return self._direct[key]


def _occluded(values: FloatArray) -> bool:
    """Every value NaN (a frame whose markers were all occluded): no observation."""
    return bool(values.size) and bool(np.isnan(values).all())


def _noise(std: Any) -> Any:
    """A noise std as an Observation holds it: a float, or an array per value."""
    arr = np.asarray(std, dtype=float)
    return float(arr) if arr.ndim == 0 else arr


def _observed_steps(spec: RunSpec) -> int:
    """The run's observed steps (a correction's covariance is weighted by them)."""
    return sum(spec.sparsity.observed(k) for k in range(1, spec.setup.steps + 1))

"""One run description, from which every key of a run derives.

A comparison is a :class:`Setup` (what every run shares: the model and its
resolved settings, the truth, the true values, the prior) times the per-run
axes (scenario, mesh, estimator and its settings, sparsity, seed). The run id,
the noise seed, the truth key, the reference-fit key and the resume check all
derive from a :class:`RunSpec`; nothing copies its fields by hand.
The noise draws derive from :meth:`RunSpec.noise_key` (common random numbers
across estimators, meshes and sparsity levels).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from idbench.core.scenario import Sparsity
from idbench.plan.config import CompareConfig
from idbench.store.files import stable_hash

Items = tuple[tuple[str, Any], ...]


@dataclass(frozen=True)
class Setup:
    """What every run of a comparison shares, fully resolved.

    Attributes
    ----------
    model
        Registered model name.
    model_settings
        The model's settings (defaults filled in) but its execution settings,
        as sorted items.
    identity
        What of the settings identifies the data (the settings dataclass's
        ``identity()`` if it has one, else all of them), JSON-able.
    truth_mesh
        The truth's discretisation.
    steps
        Load steps K.
    true
        True value of every parameter, in the model's parameter order.
    prior
        Prior (mean, std) of every parameter.
    reference
        Estimator whose fit gives the reference value.
    execution
        The model's execution settings (see
        :func:`idbench.core.settings.execution_names`), as sorted items: passed to the
        model, left out of every key and of the run id.
    data
        A recording the runs observe instead of a simulated truth
        (:mod:`idbench.store.recording`): (its folder, the digest of its content);
        empty: the truth is simulated.
    """

    model: str
    model_settings: Items
    identity: tuple[Any, ...]
    truth_mesh: str
    steps: int
    true: Items
    prior: tuple[float, float]
    reference: str
    execution: Items = ()
    data: tuple[str, ...] = ()

    @property
    def names(self) -> tuple[str, ...]:
        """Parameter names."""
        return tuple(n for n, _ in self.true)

    def _true_key(self) -> Any:
        values = [v for _, v in self.true]
        return values[0] if len(values) == 1 else values


@dataclass(frozen=True)
class RunSpec:
    """One run: the shared set-up and the run's own axes; small and picklable.

    ``timeout`` is how long the run may take, not what it computes: it is left
    out of every key. ``posterior`` (the reference posterior's settings as
    items, None: no posterior) adds columns to the run's row but does not
    change its estimate: it is left out of the run id too. ``inputs`` is a
    digest of what the run's models read (their ``describe()``, which holds
    a digest of each file's content, see :func:`idbench.plan.check.plan`): it is
    part of the run id, so that a run on a mesh or body file whose content
    changed is another run, but of no other key (the noise draws and the
    caches do not depend on it). ``observe`` names the run's observation
    model (:mod:`idbench.observe.kinds`) and ``observe_settings`` holds its resolved
    settings per block (empty for plain ``markers``, whose keys and run ids
    are those of before observation models).
    """

    setup: Setup
    scenario: str
    mesh: str
    estimator: str
    settings: Items
    seed: int
    obs_every: int
    obs_points: int
    noise: float
    timeout: float | None = None
    posterior: Items | None = None
    inputs: str = ""
    observe: str = "markers"
    observe_settings: Items = ()
    calibration: Items | None = None

    @property
    def run_id(self) -> str:
        """Deterministic hash of the run description and of its inputs' content.

        The timeout, the posterior settings and the execution settings are
        left out, and so are the calibration settings of an uncorrected run
        (None).
        """
        fields = dataclasses.asdict(self)
        fields.pop("timeout")
        fields.pop("posterior")
        if fields["calibration"] is None:
            fields.pop("calibration")
        fields["setup"].pop("execution")
        fields["setup"].pop("data")
        if self.setup.data:  # its content, not where it lies
            fields["data"] = self.setup.data[1]
        if not self.observed_otherwise():
            fields.pop("observe")
            fields.pop("observe_settings")
        return stable_hash(fields)

    def observed_otherwise(self) -> bool:
        """Whether the run observes anything but plain markers."""
        return self.observe != "markers" or bool(self.observe_settings)

    def observe_kind(self) -> str:
        """The observation models that run, by kind (``cloud`` for ``cloud500``).

        Each block of :attr:`observe` (``A+B``) as the kind its settings
        resolved it to: a table's ``kind``, else the block's own name.
        """
        resolved = {block: dict(items).get("kind", block)
                    for block, items in self.observe_settings}  # fmt: skip
        return "+".join(
            str(resolved.get(b.strip(), b.strip())) for b in self.observe.split("+")
        )

    def _observe_key(self) -> list[Any]:
        if not self.observed_otherwise():
            return []
        blocks = [[b, [list(i) for i in s]] for b, s in self.observe_settings]
        return [self.observe, blocks]

    @property
    def sparsity(self) -> Sparsity:
        """The run's sparsity settings."""
        return Sparsity(self.obs_every, self.obs_points, self.noise)

    def data_key(self) -> list[Any]:
        """What the observation stream depends on (not estimator or model mesh)."""
        s = self.setup
        return [
            s.model, self.scenario, s.truth_mesh, s.steps, s._true_key(),
            *s.identity, self.obs_every, self.obs_points, self.noise, self.seed,
            *self._observe_key(), *s.data[1:],
        ]  # fmt: skip

    def noise_key(self) -> list[Any]:
        """What the standard-normal noise draws depend on; its hash seeds them.

        Common random numbers: the draws are shared by every estimator, model
        mesh, noise level and observation spacing of a sweep (scaled by the
        noise sigma, selected by the spacing), so comparisons across them are
        paired. The markers stay in the key: they set the observation size.
        Each block of another observation model seeds its own generator from
        this key and its ``identity()``
        (:class:`~idbench.core.observation_model.ObservationModel`, see
        :meth:`idbench.run.session.Session.frames`).
        """
        s = self.setup
        return [
            s.model, self.scenario, s.truth_mesh, s.steps, s._true_key(),
            *s.identity, self.obs_points, self.seed, *s.data[1:],
        ]  # fmt: skip

    def reference_key(self) -> str:
        """What the reference fit depends on: runs with the same key share one."""
        s = self.setup
        return stable_hash([self.data_key(), self.mesh, s.reference, list(s.prior)])

    def model_key(self, mesh: str, scenario: str, role: str) -> str:
        """Identity of the forward model of ``mesh`` on ``scenario`` in ``role``."""
        s = self.setup
        return stable_hash(
            [s.model, list(s.model_settings), mesh, scenario, s.steps,
             self.obs_points, role]
        )  # fmt: skip

    def truth_product_key(self, scenario: str) -> str:
        """Identity of the probed truth of ``scenario`` (model and true values)."""
        truth = self.model_key(self.setup.truth_mesh, scenario, "truth")
        key = [truth, [list(item) for item in self.setup.true]]
        if self.setup.data:  # a recorded truth, probed for this run's mesh
            key += [self.setup.data[1], self.mesh]
        return stable_hash(key)

    def direct_key(self, scenario: str) -> str:
        """Identity of the direct run: the run's mesh on ``scenario`` at the truth."""
        model = self.model_key(self.mesh, scenario, "metrics")
        return stable_hash(
            [model, [list(item) for item in self.setup.true], *self.setup.data[1:]]
        )


def expand(
    config: CompareConfig, setup: Setup, observe: dict[str, Items] | None = None
) -> list[RunSpec]:
    """The runs of a resolved comparison, in a stable order.

    ``observe`` maps each ``config.observe`` name to its resolved settings
    (:func:`idbench.observe.kinds.settings_items`; default: none).
    """
    observe = observe or {}
    assert config.is_resolved(), "resolve the config first"
    runs = []
    posterior = (
        tuple(sorted(config.posterior_settings.items())) if config.posterior else None
    )
    for scenario in config.scenarios or ():
        for mesh in config.meshes or ():
            for sp, obs in (
                (sp, obs) for obs in config.observe for sp in config.sparsities()
            ):
                for estimator in config.estimators or ():
                    settings = config.estimator_settings.get(estimator, {})
                    calibration = calibration_items(config, scenario, settings)
                    for seed in range(config.seeds):
                        runs.append(
                            RunSpec(
                                setup=setup,
                                scenario=scenario,
                                mesh=mesh,
                                estimator=estimator,
                                settings=tuple(sorted(settings.items())),
                                seed=seed,
                                obs_every=sp.obs_every,
                                obs_points=sp.obs_points,
                                noise=float(sp.noise),
                                timeout=config.timeout,
                                posterior=posterior,
                                observe=obs,
                                observe_settings=observe.get(obs, ()),
                                calibration=calibration,
                            )
                        )
    return runs


def calibration_items(
    config: CompareConfig, scenario: str, settings: dict[str, Any]
) -> Items | None:
    """The calibration settings of a run, resolved; None for an uncorrected one.

    A run is corrected when its estimator settings say ``correction`` other
    than ``"none"``. The calibration mesh defaults to the truth mesh spec, its
    scenarios to the run's own.
    """
    if settings.get("correction", "none") == "none":
        return None
    given = dict(config.calibration)
    given["mesh"] = given.get("mesh") or config.truth_mesh
    names = given.get("scenarios") or (scenario,)
    given["scenarios"] = (names,) if isinstance(names, str) else tuple(names)
    return tuple(sorted(given.items()))

"""What a calibration simulates: the prior draws, the paths and their samples.

A :class:`Design` ``draws`` parameters theta_j from the prior (a seeded
:class:`numpy.random.Generator`; a log-normal with the prior's mean and
variance), and every calibration scenario: the fine and the coarse path at
each theta_j, every step a sample. A model whose loads are dead and ramp
linearly with the step and whose law is linear in its one parameter (a
displacement field depends on the load only through f / E) says so with the
attribute ``load_scaling = True`` (see :data:`LOAD_SCALING`); without the
attribute the property is checked on the coarse model (two short solves)
and used if it holds. Then one fine path per scenario, at the prior's
``quantile`` of theta and with ``scaled_steps`` steps, holds every load state
of every draw (a draw theta_j at step k is the load fraction
(k / K) theta_lo / theta_j of it): its steps are the samples. The cost is
reported in fine path simulations (fine steps / K). The fine paths are
cached as truths (:func:`fine_path`).

What is fitted to the samples: :mod:`idbench.calibrate.discrepancy` (the
maths) and :mod:`idbench.calibrate.fit`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace

import numpy as np

from idbench.calibrate.discrepancy import FEATURES, FIT_VERSION
from idbench.core.capabilities import member
from idbench.core.interfaces import (
    FloatArray,
    ForwardModel,
    ModelFailure,
    ModelSpec,
    Prior,
)
from idbench.core.scenario import Scenario
from idbench.core.settings import check_choice
from idbench.estimate.transforms import LogTransform
from idbench.store.files import stable_hash
from idbench.truth.cache import cache_dir, read_states, write_states
from idbench.truth.simulate import probe, truth_key

log = logging.getLogger(__name__)


LOAD_SCALING = "load_scaling"
"""Optional model attribute (bool): True declares that the state at step k of
a path with parameter theta (p = 1) depends on (k, theta) only through
(k / K) / theta (dead loads ramped linearly with k, a law linear in theta);
False declares it does not hold. Absent: checked numerically."""

SCALING_TOLERANCE = 1e-6
"""Relative difference under which the load scaling counts as holding."""


@dataclass(frozen=True)
class CalibrationSettings:
    """How a coarse mesh is calibrated against a finer one.

    Attributes
    ----------
    mesh
        The finer mesh of the same body (``""``: the comparison's truth mesh
        spec; the calibration still simulates its own paths).
    scenarios
        Load paths of the design (``()``: the comparison's scenarios).
    draws
        Number of prior draws theta_j (without load scaling: fine paths per
        scenario).
    seed
        Seed of the draws.
    quantile
        With load scaling: the one fine path runs at this prior quantile of
        theta, so it covers the load states of every theta above it.
    scaled_steps
        With load scaling: steps of that fine path.
    features
        ``"linear"`` or ``"quadratic"`` features of the coarse observation.
    ridge
        Ridge penalty (relative to the mean diagonal of Phi^T Phi).
    """

    mesh: str = ""
    scenarios: tuple[str, ...] = ()
    draws: int = 8
    seed: int = 0
    quantile: float = 0.05
    scaled_steps: int = 60
    features: str = "quadratic"
    ridge: float = 1e-8

    def __post_init__(self) -> None:
        if not isinstance(self.draws, int) or self.draws < 1:
            raise ValueError(f"draws = {self.draws!r}: need an integer >= 1")
        if not 0 < self.quantile < 0.5:
            raise ValueError(f"quantile = {self.quantile!r}: need 0 < q < 0.5")
        if not isinstance(self.scaled_steps, int) or self.scaled_steps < 2:
            raise ValueError(
                f"scaled_steps = {self.scaled_steps!r}: need an integer >= 2"
            )
        check_choice("features", self.features, FEATURES)
        if not (math.isfinite(self.ridge) and self.ridge >= 0):
            raise ValueError(f"ridge = {self.ridge!r}: need a finite value >= 0")


def prior_draws(prior: Prior, draws: int, seed: int) -> FloatArray:
    """``draws`` parameter vectors (N, p) from the prior's log-normal, seeded."""
    mu, cov = LogTransform().prior_xi(prior, len(prior.mean))
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((draws, mu.size))
    return np.exp(mu[None, :] + z * np.sqrt(np.diag(cov))[None, :])


def prior_quantile(prior: Prior, q: float) -> FloatArray:
    """The prior log-normal's q-quantile of each parameter (p,)."""
    from scipy.stats import norm

    mu, cov = LogTransform().prior_xi(prior, len(prior.mean))
    return np.exp(mu + float(norm.ppf(q)) * np.sqrt(np.diag(cov)))


def scaling_holds(model: ForwardModel) -> bool:
    """Whether ``model`` declares, or shows, the load scaling (:data:`LOAD_SCALING`).

    The check (when the model declares nothing): with a fixed theta, step 2
    from the unloaded state through step 1 equals step 1 at theta / 2.
    """
    declared = member(model, LOAD_SCALING)
    if declared is not None:
        return bool(declared) and model.parameters.p == 1
    if model.parameters.p != 1 or model.n_steps < 2:
        return False
    lo, hi = model.parameters.lower[0], model.parameters.upper[0]
    theta = np.array([math.sqrt(max(lo, 1e-300) * hi) if lo > 0 else 1.0])
    try:
        u0 = model.reset()
        a = model.step(theta, 2, model.step(theta, 1, u0))
        b = model.step(theta / 2, 1, u0)
    except Exception:
        return False
    size = max(float(np.max(np.abs(a))), 1e-300)
    return bool(np.max(np.abs(a - b)) <= SCALING_TOLERANCE * size)


@dataclass(frozen=True)
class Samples:
    """Calibration samples: coarse observation z, discrepancies, their scenario.

    Attributes
    ----------
    z
        Coarse marker displacements (n, m).
    d_obs
        Fine minus coarse marker displacements (n, m).
    d_grid
        Fine minus coarse grid displacements (n, G d).
    group
        Index of the scenario of each sample (n,).
    d_targets
        Fine minus coarse hidden-target displacements (n, 3 T), T = 0 for a
        model without targets.
    grid_dim
        d, the components of a grid point (the grid is (G, d)).
    """

    z: FloatArray
    d_obs: FloatArray
    d_grid: FloatArray
    group: FloatArray
    d_targets: FloatArray | None = None
    grid_dim: int = 3


Factory = Callable[[ModelSpec], ForwardModel]


@dataclass(frozen=True)
class Design:
    """What a calibration simulates: the coarse model, the finer mesh, the paths.

    Attributes
    ----------
    factory
        The registered model factory (the same model on both meshes).
    coarse
        The coarse model's spec (its scenario is replaced by each of
        ``scenarios``; its markers and settings are kept).
    fine_mesh
        The finer mesh of the same body.
    scenarios
        The design's load paths.
    prior
        The prior the design draws from.
    settings
        The design and the regression.
    """

    factory: Factory
    coarse: ModelSpec
    fine_mesh: str
    scenarios: Sequence[Scenario]
    prior: Prior
    settings: CalibrationSettings

    def key(self) -> str:
        """Cache key: both models' descriptions per scenario, prior, settings."""
        from idbench.core.version import __version__

        descs = []
        for sc in self.scenarios:
            for mesh in (self.coarse.mesh, self.fine_mesh):
                spec = replace(self.coarse, mesh=mesh, scenario=sc)
                descs.append(self.factory(spec).describe())
        prior = [list(self.prior.mean), list(self.prior.std)]
        return stable_hash(
            {"models": descs, "prior": prior, "settings": asdict(self.settings),
             "version": __version__, "fit": FIT_VERSION},
            length=24,
        )  # fmt: skip

    def samples(self) -> tuple[Samples, float, bool]:
        """Fine and coarse paths over the design; the samples and their fine cost.

        Returns the samples, the fine path simulations they took (fine steps /
        K) and whether the load scaling was used.
        """
        factory, coarse, settings = self.factory, self.coarse, self.settings
        scaled = scaling_holds(factory(coarse))
        K = coarse.n_steps
        zs, dos, dgs, dts, groups = [], [], [], [], []
        dim = 3
        fine_steps = 0
        for g, scenario in enumerate(self.scenarios):
            if scaled:
                steps = settings.scaled_steps
                thetas = prior_quantile(self.prior, settings.quantile)[None, :]
            else:
                steps = K
                thetas = prior_draws(self.prior, settings.draws, settings.seed)
            fine = factory(replace(coarse, mesh=self.fine_mesh, scenario=scenario,
                                   n_steps=steps))  # fmt: skip
            crs = factory(replace(coarse, scenario=scenario, n_steps=steps))
            for theta in thetas:
                path = probe(fine, fine_path(fine, theta))  # cached like a truth
                fine_steps += len(path.states)
                states = _reach(crs, theta, len(path.states))
                n = len(states)
                if n < steps:
                    log.warning("calibration of %s on %s: load states up to step %d "
                                "of %d (the models fail beyond)", coarse.mesh,
                                scenario.name, n, steps)  # fmt: skip
                z = np.array([crs.observe(s) for s in states])
                zg = np.array([np.ravel(crs.grid(s)) for s in states])
                dim = int(np.shape(path.grid)[-1])
                zs.append(z)
                dos.append(path.observations[:n] - z)
                dgs.append(path.grid[:n].reshape(n, -1) - zg)
                dts.append(_target_discrepancy(crs, states, path.targets))
                groups.append(np.full(n, g))
        samples = Samples(np.vstack(zs), np.vstack(dos), np.vstack(dgs),
                          np.concatenate(groups).astype(float), np.vstack(dts),
                          dim)  # fmt: skip
        return samples, fine_steps / K, scaled


def _target_discrepancy(
    coarse: ForwardModel, states: FloatArray, fine: FloatArray | None
) -> FloatArray:
    """Fine minus coarse target displacements (n, 3 T); (n, 0) without targets."""
    targets = member(coarse, "targets")
    n = len(states)
    if not callable(targets) or fine is None:
        return np.zeros((n, 0))
    moved = np.array([np.ravel(targets(s)) for s in states], dtype=float)
    return np.asarray(fine[:n].reshape(n, -1) - moved)


def _reach(model: ForwardModel, theta: FloatArray, n: int) -> FloatArray:
    """States (k, n_state) of steps 1..k <= n, stopping at the first failure."""
    state = model.reset()
    states = []
    for k in range(1, n + 1):
        try:
            state = model.step(theta, k, state)
        except ModelFailure:
            break
        if not np.all(np.isfinite(state)):
            break
        states.append(state)
    if not states:
        raise ModelFailure("the calibration path fails at its first step", step=1)
    return np.array(states)


def fine_path(model: ForwardModel, theta: FloatArray) -> FloatArray:
    """The fine path's states at ``theta`` as far as the model solves it, cached.

    A complete path is cached as a truth (:func:`idbench.truth.simulate.simulate_truth`
    finds it); one that fails at step k (a load beyond what the mesh bears) is
    cached with its steps 1..k-1 (``reached-KEY.npz``), so that it is not
    simulated again.
    """
    key = truth_key(model, theta)
    full = cache_dir() / f"truth-{key}.npz"
    shape = (model.n_steps, model.reset().size)
    states = read_states(full, key, shape)
    if states is not None:
        return states
    part = cache_dir() / f"reached-{key}.npz"
    if part.exists():
        try:
            with np.load(part, allow_pickle=False) as data:
                rows = int(np.shape(data["states"])[0])
        except Exception:  # damaged: read_states warns and it is recomputed below
            rows = 0
        found = read_states(part, key, (rows, shape[1]))
        if found is not None and 0 < rows < shape[0]:
            return found
    log.info("simulating calibration path %s", key)
    states = _reach(model, theta, model.n_steps)
    write_states(full if len(states) == model.n_steps else part, key, states)
    return states

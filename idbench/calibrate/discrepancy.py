r"""The approximation error of a coarse mesh: calibrated offline against a finer one.

The Bayesian approximation error approach (Kaipio & Somersalo 2007): a
coarse model h_c is a fine model h_f plus a discrepancy,

.. math::

    y = h_f(u_f(\theta)) + e = h_c(u_c(\theta)) + d(\theta) + e, \qquad
    d = h_f(u_f) - h_c(u_c),

and d, sampled offline over the prior with the fine and the coarse model of
the same body (never the comparison's truth data), is modelled as Gaussian.
Here it is conditioned on the *load state*, which the coarse model's own
predicted observation z = h_c(u_c) represents (for one load direction the
load state, the step and theta enter only through it). Over the samples
(z_i, d_i), a weighted ridge regression on the features phi(z) (``"linear"``:
1, z; ``"quadratic"``: also every z_a z_b) gives the mean
mu(z) = W^T phi(z); its residuals, modelled as relative to the displacement
(variance C (t_i + t_0), t = |z|^2 / z_s^2, z_s the RMS sample |z|, weights
w_i = 1 / (t_i + t_0)), give the covariance of a prediction,

.. math::

    \Sigma(z) = C \, \big(t(z) + t_0 + h(z)\big), \qquad
    h(z) = \phi(z)^T (\Phi^T W \Phi)^{-1} \phi(z),

C the larger of the in-sample and the leave-one-scenario-out residual
covariance (see :func:`fit`), the leverage h growing where z leaves the
calibrated load states (a load
direction the design did not span): there the correction extrapolates, and
:meth:`Discrepancy.extrapolates` says so. The corrected observation model an
estimator uses is

.. math::

    y = h_c(x) + \mu(h_c(x)) + e, \qquad e \sim N(0, R + n_{obs} \Sigma(h_c(x))).

The factor n_obs (the observed steps of the run): the discrepancy is the
same systematic error at every step, not fresh noise; for an error shared by
n observations, n independent ones of n times its covariance carry the same
information about theta (exact for a linear model with a constant error).

The design. ``draws`` parameters theta_j from the prior (a seeded
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
reported in fine path simulations (fine steps / K).

The same regression (the same features and weights) gives the mean
discrepancy of the shape-error grid and of the hidden targets (a model with
``targets``), and per grid point and per target a residual covariance
(3 x 3, from the same in-sample or leave-one-scenario-out residuals as C)
that grows with z like Sigma: the predictive uncertainty of a corrected
shape is the parameter's propagated covariance plus this one
(:func:`idbench.score.targets.grid_columns`).

The fitted :class:`Discrepancy` is cached on disk like the truth
(:mod:`idbench.truth.cache`'s folder, a hash of both models' descriptions, the
prior, the settings and the version; atomic writes, a content digest
checked on load), and so are its fine paths (as truths).
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from idbench.core.capabilities import member
from idbench.core.interfaces import (
    Cost,
    FloatArray,
    ForwardModel,
    ModelFailure,
    ModelSpec,
    Prior,
)
from idbench.core.scenario import Scenario
from idbench.core.settings import check_choice
from idbench.estimate.transforms import LogTransform
from idbench.store.files import digest, stable_hash
from idbench.truth.cache import (
    cache_dir,
    read_entry,
    read_states,
    write_entry,
    write_states,
)
from idbench.truth.simulate import probe, truth_key

log = logging.getLogger(__name__)

LOAD_SCALING = "load_scaling"
"""Optional model attribute (bool): True declares that the state at step k of
a path with parameter theta (p = 1) depends on (k, theta) only through
(k / K) / theta (dead loads ramped linearly with k, a law linear in theta);
False declares it does not hold. Absent: checked numerically."""

FEATURES = ("linear", "quadratic")

FLOOR = 1e-4
"""t_0: the residual variance floor, relative to the squared RMS sample |z|."""

FIT_VERSION = 3
"""Changes when the fit changes (the cache keys on it); 2: C from the
leave-one-scenario-out residuals where they interpolate; 3: the targets'
discrepancy and the grid's and targets' residual covariances."""

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


# --- features ---------------------------------------------------------------


def _features(z: FloatArray, scale: float, kind: str) -> FloatArray:
    """phi(z) (n, F) of observations z (n, m), scaled by ``scale``."""
    x = np.atleast_2d(z) / scale
    cols = [np.ones((x.shape[0], 1)), x]
    if kind == "quadratic":
        a, b = np.triu_indices(x.shape[1])
        cols.append(x[:, a] * x[:, b])
    return np.hstack(cols)


def _feature_jacobian(z: FloatArray, scale: float, kind: str) -> FloatArray:
    """The feature Jacobian d phi / d z (F, m) at one observation z (m,)."""
    m = z.size
    x = z / scale
    rows = [np.zeros((1, m)), np.eye(m) / scale]
    if kind == "quadratic":
        a, b = np.triu_indices(m)
        jq = np.zeros((a.size, m))
        jq[np.arange(a.size), a] += x[b] / scale
        jq[np.arange(a.size), b] += x[a] / scale
        rows.append(jq)
    return np.vstack(rows)


# --- the fitted discrepancy -------------------------------------------------


@dataclass(frozen=True)
class Discrepancy:
    """A coarse mesh's approximation error as a function of its observation.

    Attributes
    ----------
    features
        ``"linear"`` or ``"quadratic"``.
    scale
        z_s, the RMS |z| of the samples (features use z / z_s).
    w_obs
        Regression weights (F, m) of the marker discrepancy.
    w_grid
        Regression weights (F, G d) of the shape-error grid discrepancy.
    cov_unit
        C (m, m), the weighted residual covariance.
    w_targets
        Regression weights (F, 3 T) of the hidden targets' discrepancy
        (T = 0: the model has no targets).
    cov_grid
        Per grid point, its residual covariance (G, d, d), like C.
    cov_targets
        Per target, its residual covariance (T, 3, 3), like C.
    a_inv
        (Phi^T W Phi + ridge)^-1 (F, F), for the prediction variance and the
        leverage.
    floor
        t_0, the relative floor of the residual variance.
    leverage_max
        The largest leverage of a sample: a z beyond it extrapolates.
    cost
        Fine path simulations the calibration took (fine steps / K).
    info
        What it was calibrated on (JSON-able): meshes, scenarios, samples,
        whether load scaling was used, the residual RMS.
    """

    features: str
    scale: float
    w_obs: FloatArray
    w_grid: FloatArray
    cov_unit: FloatArray
    a_inv: FloatArray
    floor: float
    leverage_max: float
    cost: float
    info: dict[str, Any] = field(default_factory=dict, hash=False)
    w_targets: FloatArray = field(default_factory=lambda: np.zeros((1, 0)))
    cov_grid: FloatArray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    cov_targets: FloatArray = field(default_factory=lambda: np.zeros((0, 3, 3)))

    def mean(self, z: FloatArray) -> FloatArray:
        """mu(z) (m,): the mean marker discrepancy at coarse observation z."""
        return np.asarray(_features(z, self.scale, self.features)[0] @ self.w_obs)

    def mean_grid(self, z: FloatArray) -> FloatArray:
        """The mean grid discrepancy (G d,) at coarse observation z."""
        return np.asarray(_features(z, self.scale, self.features)[0] @ self.w_grid)

    def mean_targets(self, z: FloatArray) -> FloatArray:
        """The mean targets' discrepancy (3 T,) at coarse observation z."""
        phi = _features(z, self.scale, self.features)[0]
        return np.asarray(phi @ self.w_targets)

    def jacobian(self, z: FloatArray) -> FloatArray:
        """The Jacobian d mu / d z (m, m) at z."""
        z = np.asarray(z, dtype=float)
        jphi = _feature_jacobian(z, self.scale, self.features)
        return np.asarray(self.w_obs.T @ jphi)

    def leverage(self, z: FloatArray) -> float:
        """h(z) = phi(z)^T A^-1 phi(z): how far z is from the samples."""
        phi = _features(z, self.scale, self.features)[0]
        return float(phi @ self.a_inv @ phi)

    def spread(self, z: FloatArray) -> float:
        """t(z) + t_0 + h(z): the factor of every residual covariance at z."""
        t = float(np.sum(np.square(z))) / self.scale**2
        return t + self.floor + self.leverage(z)

    def cov(self, z: FloatArray) -> FloatArray:
        """Sigma(z) = C (|z|^2 / z_s^2 + t_0 + h(z)) (m, m)."""
        return np.asarray(self.cov_unit * self.spread(z))

    def grid_cov(self, z: FloatArray) -> FloatArray:
        """The grid discrepancy's covariance per point (G, d, d) at z."""
        return np.asarray(self.cov_grid * self.spread(z))

    def targets_cov(self, z: FloatArray) -> FloatArray:
        """The targets' discrepancy covariance per target (T, 3, 3) at z."""
        return np.asarray(self.cov_targets * self.spread(z))

    def extrapolates(self, z: FloatArray) -> bool:
        """Whether z lies beyond the calibrated load states (leverage above all)."""
        return self.leverage(z) > self.leverage_max * (1 + 1e-9)

    # --- storage ----------------------------------------------------------

    def arrays(self) -> dict[str, FloatArray]:
        """The numeric content, by name (what is stored and digested)."""
        return {
            "w_obs": self.w_obs,
            "w_grid": self.w_grid,
            "cov_unit": self.cov_unit,
            "a_inv": self.a_inv,
            "w_targets": self.w_targets,
            "cov_grid": self.cov_grid,
            "cov_targets": self.cov_targets,
            "scalars": np.array(
                [self.scale, self.floor, self.leverage_max, self.cost]
            ),
        }

    def save(self, path: Path, key: str) -> None:
        """Write to ``path`` (``.npz``, no pickle) atomically, with a digest."""
        arrays = self.arrays()
        meta = json.dumps({"features": self.features, "info": self.info})
        check = digest(np.concatenate([a.ravel() for a in arrays.values()]))
        content = {"meta": np.array(meta), "digest": np.array(check), **arrays}
        write_entry(path, key, content, "discrepancy")

    @classmethod
    def load(cls, path: Path, key: str) -> Discrepancy | None:
        """The entry at ``path`` if its key and content digest match, else None."""
        names = ("w_obs", "w_grid", "cov_unit", "a_inv", "w_targets", "cov_grid",
                 "cov_targets", "scalars")  # fmt: skip

        def check(data: dict[str, Any]) -> None:
            arrays = [np.asarray(data[n], dtype=float).ravel() for n in names]
            if str(data["digest"]) != digest(np.concatenate(arrays)):
                raise ValueError("content digest mismatch (altered or damaged)")
            meta = json.loads(str(data["meta"]))
            if not isinstance(meta.get("features"), str) or "info" not in meta:
                raise ValueError("meta without features or info")

        data = read_entry(path, key, check, "discrepancy")
        if data is None:
            return None
        arrays = {n: np.array(data[n], dtype=float) for n in names}
        meta = json.loads(str(data["meta"]))
        scale, floor, lev, cost = arrays.pop("scalars")
        return cls(features=meta["features"], scale=float(scale), floor=float(floor),
                   leverage_max=float(lev), cost=float(cost), info=meta["info"],
                   **arrays)  # fmt: skip


# --- the design ---------------------------------------------------------------


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
    declared = getattr(model, LOAD_SCALING, None)
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


def _psd(a: FloatArray) -> FloatArray:
    """The nearest symmetric positive semi-definite matrix (eigenvalues clipped)."""
    w, v = np.linalg.eigh(0.5 * (a + a.T))
    return np.asarray((v * np.clip(w, 0, None)) @ v.T)


def _weighted_fit(
    phi: FloatArray, w: FloatArray, ridge: float
) -> FloatArray:
    """(Phi^T W Phi + ridge')^-1 (F, F), the intercept not penalised."""
    a = (phi * w[:, None]).T @ phi
    pen = ridge * float(np.mean(np.diag(a))) * np.eye(a.shape[0])
    pen[0, 0] = 0.0
    return np.asarray(np.linalg.pinv(a + pen, hermitian=True))


def fit(samples: Samples, settings: CalibrationSettings) -> Discrepancy:
    """Weighted ridge regression of the discrepancy on the coarse observation.

    The residual of a sample is modelled as N(0, C (t_i + t_0)), t_i =
    |z_i|^2 / z_s^2 (an error relative to the displacement, with a floor t_0
    = :data:`FLOOR`), so the weights are w_i = 1 / (t_i + t_0) and C is the
    weighted residual covariance. With two or more scenarios, C is the larger
    (by trace) of the in-sample one and that of the leave-one-scenario-out
    residuals where the others' fit interpolates (each scenario predicted by
    a fit on the others): how far the correction transfers to a path it did
    not see (``info["covariance"]`` says which; ``info["loso_rms"]`` is the
    RMS of every held-out residual, extrapolations included).
    """
    z = samples.z
    scale = float(np.sqrt(np.mean(np.sum(z**2, axis=1)))) or 1.0
    phi = _features(z, scale, settings.features)
    t = np.sum(z**2, axis=1) / scale**2
    w = 1.0 / (t + FLOOR)
    a_inv = _weighted_fit(phi, w, settings.ridge)
    pw = (phi * w[:, None]).T
    d_targets = samples.d_targets
    if d_targets is None:
        d_targets = np.zeros((len(z), 0))
    m, ng = samples.d_obs.shape[1], samples.d_grid.shape[1]
    y = np.hstack([samples.d_obs, samples.d_grid, d_targets])
    weights = a_inv @ (pw @ y)
    w_obs, w_grid, w_targets = weights[:, :m], weights[:, m:m + ng], weights[:, m + ng:]
    every = y - phi @ weights
    res = every[:, :m]
    dof = max(len(z) - phi.shape[1], 1)
    cov_unit = _psd((res * w[:, None]).T @ res / dof)
    blocks = _block_cov(every[:, m:], w, dof, samples.grid_dim, ng)
    leverage = np.einsum("ij,jk,ik->i", phi, a_inv, phi)
    info: dict[str, Any] = {
        "samples": len(z),
        "residual_rms": float(np.sqrt(np.mean(res**2))),
        "discrepancy_rms": float(np.sqrt(np.mean(samples.d_obs**2))),
        "covariance": "in-sample",
    }
    transfer = _transfer_residuals(phi, w, samples.group, y, m, settings.ridge)
    if transfer is not None:
        r_all, w_out, rms = transfer
        info["loso_rms"] = rms
        r_out = r_all[:, :m]
        if len(r_out) > phi.shape[1]:
            cov_out = _psd((r_out * w_out[:, None]).T @ r_out / len(r_out))
            if np.trace(cov_out) > np.trace(cov_unit):
                cov_unit, info["covariance"] = cov_out, "leave-one-scenario-out"
                blocks = _block_cov(r_all[:, m:], w_out, len(r_out),
                                    samples.grid_dim, ng)  # fmt: skip
    cov_grid, cov_targets = blocks
    return Discrepancy(settings.features, scale, w_obs, w_grid, cov_unit, a_inv,
                       FLOOR, float(leverage.max()), 0.0, info, w_targets,
                       cov_grid, cov_targets)  # fmt: skip


def _block_cov(
    res: FloatArray, w: FloatArray, dof: int, dim: int, ng: int
) -> tuple[FloatArray, FloatArray]:
    """Per-point weighted residual covariances of the grid (G, d, d) and targets.

    ``res`` (n, G d + 3 T): the grid's residuals, then the targets'.
    """
    n = len(res)
    grid = res[:, :ng].reshape(n, -1, dim)
    tgt = res[:, ng:].reshape(n, -1, 3)
    out = []
    for r in (grid, tgt):
        out.append(np.einsum("i,ipj,ipk->pjk", w, r, r) / dof)
    return out[0], out[1]


def _transfer_residuals(
    phi: FloatArray, w: FloatArray, group: FloatArray, y: FloatArray, m: int,
    ridge: float,
) -> tuple[FloatArray, FloatArray, float] | None:
    """Leave-one-scenario-out residuals where the others' fit interpolates.

    Each scenario is predicted by a fit on the others; its samples within
    that fit's largest training leverage (where the fit would not flag an
    extrapolation) give the residuals of every column of ``y`` and their
    weights. Also returns the RMS of every held-out residual of the first
    ``m`` columns (the markers). None with fewer than two scenarios.
    """
    groups = np.unique(group)
    if groups.size < 2:
        return None
    kept_r, kept_w, every = [], [], []
    for g in groups:
        out = group == g
        ai = _weighted_fit(phi[~out], w[~out], ridge)
        wg = ai @ ((phi[~out] * w[~out, None]).T @ y[~out])
        r = y[out] - phi[out] @ wg
        every.append(r[:, :m])
        lev_in = np.einsum("ij,jk,ik->i", phi[~out], ai, phi[~out]).max()
        lev_out = np.einsum("ij,jk,ik->i", phi[out], ai, phi[out])
        inside = lev_out <= lev_in
        kept_r.append(r[inside])
        kept_w.append(w[out][inside])
    rms = float(np.sqrt(np.mean(np.vstack(every) ** 2)))
    return np.vstack(kept_r), np.concatenate(kept_w), rms


def fit_discrepancy(
    factory: Factory,
    coarse: ModelSpec,
    fine_mesh: str,
    scenarios: Sequence[Scenario],
    prior: Prior,
    settings: CalibrationSettings | None = None,
    *,
    cache: bool = True,
) -> Discrepancy:
    """The approximation error of ``coarse`` against ``fine_mesh`` (cached on disk).

    Parameters
    ----------
    factory, coarse, fine_mesh, scenarios, prior
        What the calibration simulates (the fields of :class:`Design`).
    settings
        The design and the regression (default :class:`CalibrationSettings`).
    cache
        Read and write the cache (the fine paths are cached as truths anyway).
    """
    settings = settings or CalibrationSettings()
    if not scenarios:
        raise ValueError("a calibration needs at least one scenario")
    design = Design(factory, coarse, fine_mesh, tuple(scenarios), prior, settings)
    key = design.key()
    path = cache_dir() / f"discrepancy-{key}.npz"
    found = Discrepancy.load(path, key) if cache else None
    if found is not None:
        return found
    log.info("calibrating %s against %s on %s", coarse.mesh, fine_mesh,
             ", ".join(s.name for s in scenarios))  # fmt: skip
    samples, cost, scaled = design.samples()
    result = fit(samples, settings)
    info = {
        **result.info, "coarse": coarse.mesh, "fine": fine_mesh,
        "scenarios": [s.name for s in scenarios], "load_scaling": scaled,
    }  # fmt: skip
    result = replace(result, cost=cost, info=info)
    if cache:
        result.save(path, key)
    return result


# --- the corrected model an estimator is handed ---------------------------------


class CorrectedModel:
    """A coarse model whose observations carry the calibrated discrepancy.

    ``observe(state) = h_c(state) + mu(h_c(state))``, ``grid`` likewise with
    the grid discrepancy, ``sensitivity`` by the chain rule
    (I + d mu / d z) J_c; every other member is the coarse model's. An
    estimator that knows it reads the extra observation covariance from
    :meth:`observation_cov` (``R + observation_cov(state)`` is its noise);
    one that does not still gets the corrected mean.

    Parameters
    ----------
    model
        The coarse forward model.
    discrepancy
        Its calibration.
    n_obs
        Observed steps of the run (the systematic error's weight, see the
        module docstring).
    """

    def __init__(self, model: ForwardModel, discrepancy: Discrepancy,
                 n_obs: int = 1) -> None:  # fmt: skip
        self.coarse = model
        self.discrepancy = discrepancy
        self.n_obs = max(int(n_obs), 1)
        self.parameters = model.parameters
        self.n_steps = model.n_steps
        self.extrapolated = 0
        if member(model, "sensitivity") is not None:
            self.sensitivity = self._sensitivity
        if member(model, "targets") is not None and discrepancy.w_targets.size:
            self.targets = self._targets

    def __getattr__(self, name: str) -> Any:
        # only called for what this class does not define: the coarse model's
        if name == "coarse":
            raise AttributeError(name)
        return getattr(self.coarse, name)

    def reset(self) -> FloatArray:
        """The coarse model's unloaded state."""
        return self.coarse.reset()

    def step(self, theta: FloatArray, k: int, state: FloatArray, *,
             substeps: int = 1) -> FloatArray:  # fmt: skip
        """The coarse model's step."""
        return self.coarse.step(theta, k, state, substeps=substeps)

    def observe(self, state: FloatArray) -> FloatArray:
        """h_c(state) + mu(h_c(state))."""
        z = np.asarray(self.coarse.observe(state), dtype=float)
        if self.discrepancy.extrapolates(z):
            self.extrapolated += 1
        return z + self.discrepancy.mean(z)

    def grid(self, state: FloatArray) -> FloatArray:
        """Coarse grid displacements plus the mean grid discrepancy."""
        g = np.asarray(self.coarse.grid(state), dtype=float)
        z = np.asarray(self.coarse.observe(state), dtype=float)
        return g + self.discrepancy.mean_grid(z).reshape(g.shape)

    def _targets(self, state: FloatArray) -> FloatArray:
        """Coarse target displacements plus the mean targets' discrepancy."""
        moved = member(self.coarse, "targets")
        t: FloatArray = np.asarray(moved(state), dtype=np.float64)
        z = np.asarray(self.coarse.observe(state), dtype=float)
        return np.asarray(t + self.discrepancy.mean_targets(z).reshape(t.shape))

    def grid_cov(self, state: FloatArray) -> FloatArray:
        """The grid prediction's discrepancy covariance per point (G, d, d)."""
        z = np.asarray(self.coarse.observe(state), dtype=float)
        return self.discrepancy.grid_cov(z)

    def targets_cov(self, state: FloatArray) -> FloatArray:
        """The targets' discrepancy covariance per target (T, 3, 3)."""
        z = np.asarray(self.coarse.observe(state), dtype=float)
        return self.discrepancy.targets_cov(z)

    def observation_cov(self, state: FloatArray) -> FloatArray:
        """n_obs Sigma(h_c(state)) (m, m): the extra observation covariance."""
        z = np.asarray(self.coarse.observe(state), dtype=float)
        return self.n_obs * self.discrepancy.cov(z)

    def _sensitivity(self, theta: FloatArray, k: int, state: FloatArray) -> FloatArray:
        sens = self.coarse.sensitivity  # type: ignore[attr-defined]
        j = np.asarray(sens(theta, k, state), dtype=np.float64)
        z = np.asarray(self.coarse.observe(state), dtype=np.float64)
        return np.asarray(j + self.discrepancy.jacobian(z) @ j)

    def cost(self) -> Cost:
        """The coarse model's cost."""
        return self.coarse.cost()

    def describe(self) -> dict[str, Any]:
        """The coarse model's description with the calibration's."""
        return {**self.coarse.describe(), "correction": self.discrepancy.info}

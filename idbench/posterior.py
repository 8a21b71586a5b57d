r"""Reference posterior of a run's parameters given its data and its model.

What an ideal Bayesian would conclude with this (coarse) model from this data:
the filters' prior times the Gaussian likelihood of the whole observation
stream, each evaluation one simulation of the load path through the
:class:`~idbench.ForwardModel` protocol (``reset``, ``step``, ``observe``).

Prior and noise are the filters' (DESIGN.md section 7): with the ``"log"``
transform xi = ln theta ~ N(mu, Sigma) with mu_j = ln m_j and
Sigma_jj = ln(1 + s_j^2 / m_j^2) (the log-normal of mean m and std s), with
``"identity"`` theta ~ N(m, diag(s^2)); R_k = max(sigma_k, floor)^2 I. Then

.. math::

    \log \pi(\xi \mid y) = \text{const} - \tfrac12 (\xi - \mu)^T \Sigma^{-1}
    (\xi - \mu) - \sum_{k \text{ observed}}
    \frac{\lVert y_k - h(u_k(\theta(\xi))) \rVert^2}{2 r_k},

truncated to the model's parameter bounds (outside them, or where the model
cannot be solved even in sub-steps, the density is 0).

- p = 1 (:func:`grid_posterior`): quadrature on a grid in xi (log-spaced in
  theta). A zooming search finds where the log density is within ``tail`` of
  its maximum (the posterior can be far narrower than the prior), then a final
  grid of ``points`` covers that region; trapezoid rule for the moments, the
  cumulative trapezoid for the quantiles.
- p >= 2 (:func:`mcmc_posterior`): the MAP by least squares in xi, then
  ``chains`` random-walk Metropolis chains started over-dispersed around it,
  proposal adapted during warm-up only (Haario et al. 2001). Converged only if
  the split R-hat across chains is below ``rhat_max`` and every chain is longer
  than ``tau_factor`` integrated autocorrelation times; otherwise
  :attr:`Posterior.converged` is False and must not be used as a reference.

The budget ``max_solves`` counts path simulations times steps simulated
(sub-step retries come on top); a budget that cannot hold the requested grid
or chains raises ValueError up front. When the model has
``step_many(thetas, k, states)`` all the paths of one batch (a grid, the
chains' proposals) advance together.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.integrate
import scipy.optimize

from idbench.interfaces import (
    FloatArray,
    ForwardModel,
    ModelFailure,
    Observation,
    Prior,
)

log = logging.getLogger(__name__)

TRANSFORMS = ("log", "identity")
METHODS = ("auto", "grid", "mcmc")
LEVELS = (0.025, 0.16, 0.5, 0.84, 0.975)
"""Probabilities of the reported quantiles (95% and 68% central intervals)."""
RETRY_SUBSTEPS = 4


@dataclass(frozen=True)
class PosteriorSettings:
    """How to compute a reference posterior; every value is checked.

    Attributes
    ----------
    transform
        ``"log"`` (default) or ``"identity"``, as the filters' setting.
    sigma_floor
        Lower bound on the noise std in R, as the filters' setting.
    method
        ``"auto"`` (grid for p = 1, MCMC otherwise), ``"grid"`` or ``"mcmc"``.
    points
        Points of the final grid (p = 1), >= 21.
    zoom_points
        Points of each zooming search grid, >= 11.
    span
        Half-width of the first search grid in prior standard deviations of xi
        (clipped to the model's bounds).
    tail
        Drop of the log density below its maximum that counts as no mass.
    max_solves
        Budget of forward solves (paths times steps simulated).
    chains, warmup, samples
        MCMC chains (>= 2), warm-up and kept iterations per chain.
    seed
        Seed of the MCMC :class:`numpy.random.Generator`.
    rhat_max
        Largest split R-hat accepted as converged.
    tau_factor
        A chain must be longer than ``tau_factor`` autocorrelation times.
    """

    transform: str = "log"
    sigma_floor: float = 1e-6
    method: str = "auto"
    points: int = 201
    zoom_points: int = 41
    span: float = 6.0
    tail: float = 25.0
    max_solves: int = 50_000
    chains: int = 4
    warmup: int = 500
    samples: int = 1000
    seed: int = 0
    rhat_max: float = 1.05
    tau_factor: float = 50.0

    def __post_init__(self) -> None:
        for name, allowed in (("transform", TRANSFORMS), ("method", METHODS)):
            if getattr(self, name) not in allowed:
                raise ValueError(
                    f"{name} = {getattr(self, name)!r} is not allowed; use one of "
                    + ", ".join(repr(a) for a in allowed)
                )
        for name, low in (
            ("points", 21),
            ("zoom_points", 11),
            ("max_solves", 1),
            ("chains", 2),
            ("warmup", 0),
            ("samples", 10),
            ("seed", 0),
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ValueError(
                    f"{name} = {v!r} is not allowed; it must be an integer >= {low}"
                )
        for name in ("sigma_floor", "span", "tail", "tau_factor"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(
                    f"{name} = {v!r} is not allowed; it must be finite > 0"
                )
        r = self.rhat_max
        if not (isinstance(r, int | float) and math.isfinite(r) and r > 1):
            raise ValueError(f"rhat_max = {r!r} is not allowed; it must be finite > 1")


@dataclass(frozen=True)
class Posterior:
    """A reference posterior in natural units.

    Attributes
    ----------
    names
        Parameter names (the model's).
    method
        ``"grid"`` or ``"mcmc"``.
    mean, std
        Posterior mean and standard deviation, shape (p,).
    quantiles
        Shape (len(levels), p): the quantiles at ``levels``.
    levels
        Probabilities of the quantiles (default :data:`LEVELS`).
    map
        Shape (p,): grid: the mode of the density of theta (a parabola through
        the largest grid value and its neighbours);
        MCMC: the maximiser of the density of xi (found by least squares).
    converged
        False when the grid is cut off by its search range while mass remains,
        or when the MCMC diagnostics fail: then do not use it as a reference.
    n_solves
        Forward solves spent (from the model's cost, retries included).
    grid, density
        p = 1 grid only: theta grid (G,) and the normalised density of theta on
        it (integrates to 1 in theta).
    samples
        MCMC only: pooled draws (chains * samples, p) of theta.
    diagnostics
        Method details (grid: ``edge_drop``, ``zooms``, ``failed``; MCMC:
        ``rhat_max``, ``tau_max``, ``ess_min``, ``acceptance``).
    """

    names: tuple[str, ...]
    method: str
    mean: FloatArray
    std: FloatArray
    quantiles: FloatArray
    levels: tuple[float, ...]
    map: FloatArray
    converged: bool
    n_solves: int
    grid: FloatArray | None = None
    density: FloatArray | None = None
    samples: FloatArray | None = None
    diagnostics: dict[str, float] = field(default_factory=dict)

    def quantile(self, level: float) -> FloatArray:
        """The quantile (p,) at one of :attr:`levels`."""
        if level not in self.levels:
            raise ValueError(f"level = {level!r} is not one of {self.levels}")
        return np.asarray(self.quantiles[self.levels.index(level)])


class _Target:
    """Log posterior density of xi for a batch of points; counts the budget."""

    def __init__(
        self,
        model: ForwardModel,
        prior: Prior,
        observations: Sequence[Observation | None],
        settings: PosteriorSettings,
    ) -> None:
        self.model = model
        self.transform = settings.transform
        p = model.parameters.p
        m = np.asarray(prior.mean, dtype=float)
        s = np.asarray(prior.std, dtype=float)
        if m.shape != (p,):
            raise ValueError(f"prior has {m.size} entries but the model has p = {p}")
        if len(observations) > model.n_steps:
            raise ValueError(
                f"{len(observations)} observations for a model of {model.n_steps} steps"
            )
        if self.transform == "log":
            if np.any(m <= 0):
                raise ValueError(f"the log transform needs a positive prior mean, {m}")
            self.mu, self.var = np.log(m), np.log1p(s**2 / m**2)
        else:
            self.mu, self.var = m, s**2
        self.obs = {}
        for i, o in enumerate(observations, start=1):
            if o is None:
                continue
            if o.step != i:
                raise ValueError(f"observation for step {o.step} at position {i}")
            std = np.asarray(o.noise_std, dtype=float)
            r: float | FloatArray = (
                max(float(std), settings.sigma_floor) ** 2
                if std.ndim == 0
                else np.maximum(std, settings.sigma_floor) ** 2
            )
            self.obs[i] = (np.asarray(o.values, dtype=float), r)
        if not self.obs:
            raise ValueError("no observations: the posterior is the prior")
        self.last = max(self.obs)
        self.lower = np.asarray(model.parameters.lower, dtype=float)
        self.upper = np.asarray(model.parameters.upper, dtype=float)
        self.budget = settings.max_solves
        self.used = 0
        self.failed = 0

    def theta(self, xi: FloatArray) -> FloatArray:
        """Natural parameters of xi (any shape)."""
        if self.transform == "log":
            with np.errstate(over="ignore"):
                return np.exp(xi)
        return np.array(xi, dtype=float)

    def xi_bounds(self) -> tuple[FloatArray, FloatArray]:
        """The model's bounds in xi (-inf where log of a bound <= 0)."""
        if self.transform == "log":
            with np.errstate(divide="ignore", invalid="ignore"):
                lo = np.where(
                    self.lower > 0, np.log(np.maximum(self.lower, 0)), -np.inf
                )
            return lo, np.log(self.upper)
        return self.lower, self.upper

    def cost(self, n_paths: int) -> int:
        """Solves of ``n_paths`` path simulations."""
        return n_paths * self.last

    def log_prior(self, xi: FloatArray) -> FloatArray:
        """Log prior density of xi (B, p) -> (B,), up to a constant."""
        return -0.5 * np.sum((xi - self.mu) ** 2 / self.var, axis=1)

    def __call__(self, xi: FloatArray) -> FloatArray:
        """Log posterior (B,) of xi (B, p), up to a constant; -inf if unsolvable."""
        xi = np.atleast_2d(np.asarray(xi, dtype=float))
        theta = self.theta(xi)
        inside = np.all(
            np.isfinite(theta) & (theta > self.lower) & (theta < self.upper), axis=1
        )
        out = np.full(xi.shape[0], -np.inf)
        idx = np.flatnonzero(inside)
        if idx.size == 0:
            return out
        need = self.cost(idx.size)
        if self.used + need > self.budget:
            raise ValueError(
                f"max_solves = {self.budget} is exhausted ({self.used} used, "
                f"{need} more needed)"
            )
        self.used += need
        loglik = self._loglik(theta[idx])
        out[idx] = self.log_prior(xi[idx]) + loglik
        return out

    def _loglik(self, thetas: FloatArray) -> FloatArray:
        model = self.model
        u0 = np.asarray(model.reset(), dtype=float)
        states = np.tile(u0, (thetas.shape[0], 1))
        ll = np.zeros(thetas.shape[0])
        alive = np.ones(thetas.shape[0], dtype=bool)
        for k in range(1, self.last + 1):
            idx = np.flatnonzero(alive)
            new, ok = _step_all(model, thetas[idx], k, states[idx])
            states[idx] = new
            alive[idx[~ok]] = False
            if k in self.obs:
                y, r = self.obs[k]
                for i in np.flatnonzero(alive):
                    h = np.asarray(model.observe(states[i]), dtype=float)
                    if np.ndim(r) == 0:
                        ll[i] -= 0.5 * float(np.sum((y - h) ** 2)) / r
                    else:  # one variance per value
                        ll[i] -= 0.5 * float(np.sum((y - h) ** 2 / r))
        self.failed += int(np.sum(~alive))
        ll[~alive] = -np.inf
        return ll


def _step_all(
    model: ForwardModel, thetas: FloatArray, k: int, states: FloatArray
) -> tuple[FloatArray, np.ndarray]:
    """Advance a batch one step; (new states, solved mask).

    ``model.step_many`` when present, then each failed member alone, once more
    in sub-steps.
    """
    new = np.array(states, dtype=float)
    ok = np.zeros(states.shape[0], dtype=bool)
    step_many = getattr(model, "step_many", None)
    if step_many is not None and states.shape[0] > 0:
        try:
            batch = np.asarray(step_many(thetas, k, states), dtype=float)
            if batch.shape == states.shape:
                ok = np.all(np.isfinite(batch), axis=1)
                new[ok] = batch[ok]
        except ModelFailure:
            pass
    for i in np.flatnonzero(~ok):
        for substeps in (1, RETRY_SUBSTEPS):
            try:
                u = np.asarray(
                    model.step(thetas[i], k, states[i], substeps=substeps), dtype=float
                )
            except ModelFailure:
                continue
            if np.all(np.isfinite(u)):
                new[i], ok[i] = u, True
                break
    return new, ok


def minimum_solves(settings: PosteriorSettings, p: int, n_steps: int) -> int:
    """Forward solves the method needs at least on a path observed at step K.

    Grid (p = 1): one search grid and the final grid; MCMC: the MAP search and
    the chains. :func:`grid_posterior` and :func:`mcmc_posterior` refuse a
    ``max_solves`` below it before solving anything.
    """
    method = settings.method
    if method == "auto":
        method = "grid" if p == 1 else "mcmc"
    if method == "grid":
        paths = settings.zoom_points + settings.points
    else:
        paths = 30 * (p + 1) + settings.chains * (settings.warmup + settings.samples)
    return paths * n_steps


def check_budget(settings: PosteriorSettings, p: int, n_steps: int) -> None:
    """Raise ValueError naming ``max_solves`` if it cannot hold the method."""
    need = minimum_solves(settings, p, n_steps)
    if need > settings.max_solves:
        method = settings.method if settings.method != "auto" else (
            "grid" if p == 1 else "mcmc"
        )
        raise ValueError(
            f"max_solves = {settings.max_solves} cannot hold the {method} "
            f"posterior of {p} parameter(s) on {n_steps} steps: it needs at "
            f"least {need} solves"
        )


def reference_posterior(
    model: ForwardModel,
    prior: Prior,
    observations: Sequence[Observation | None],
    settings: PosteriorSettings | None = None,
) -> Posterior:
    """The posterior of the model's parameters given a run's observations.

    Parameters
    ----------
    model
        The (coarse) forward model the estimators use.
    prior
        The run's prior in natural units.
    observations
        The run's stream: entry k-1 is step k's observation or None.
    settings
        Method, grid, budget; default :class:`PosteriorSettings`.

    Returns
    -------
    Posterior
        Grid quadrature for p = 1, MCMC for p >= 2 (``method = "auto"``).
    """
    settings = settings or PosteriorSettings()
    method = settings.method
    if method == "auto":
        method = "grid" if model.parameters.p == 1 else "mcmc"
    if method == "grid":
        return grid_posterior(model, prior, observations, settings)
    return mcmc_posterior(model, prior, observations, settings)


def grid_posterior(
    model: ForwardModel,
    prior: Prior,
    observations: Sequence[Observation | None],
    settings: PosteriorSettings | None = None,
) -> Posterior:
    """The posterior of a single parameter (p = 1) by quadrature on a grid in xi.

    Search: a grid of ``zoom_points`` over mu +- span sd (within the bounds);
    keep the points within ``tail`` of the maximum and one neighbour each side;
    zoom into them until they hold at least 8 points (at most 20 zooms), then a
    final grid of ``points`` over that range. ``converged`` is False when the
    final grid's ends are within ``tail / 2`` of the maximum at a search edge
    that is not a model bound (mass cut off), or fewer than 5 of its points lie
    within 5 of the maximum (not resolved).
    """
    settings = settings or PosteriorSettings()
    if model.parameters.p != 1:
        raise ValueError(
            f"a grid posterior needs p = 1, the model has p = {model.parameters.p}"
        )
    target = _Target(model, prior, observations, settings)
    need = target.cost(settings.zoom_points + settings.points)
    if need > settings.max_solves:
        raise ValueError(
            f"max_solves = {settings.max_solves} cannot hold one search grid and "
            f"the final grid ({need} solves)"
        )
    cost0 = model.cost()
    sd = math.sqrt(float(target.var[0]))
    blo, bhi = (float(b[0]) for b in target.xi_bounds())
    mu = float(target.mu[0])
    lo0, hi0 = mu - settings.span * sd, mu + settings.span * sd
    at_lower, at_upper = lo0 <= blo, hi0 >= bhi  # a model bound truncates
    if at_lower:
        lo0 = blo + 1e-9 * max(1.0, abs(blo))  # the bounds are open
    if at_upper:
        hi0 = bhi - 1e-9 * max(1.0, abs(bhi))
    lo, hi = lo0, hi0
    zooms = 0
    while True:
        xs = np.linspace(lo, hi, settings.zoom_points)
        lp = target(xs[:, None])
        if not np.any(np.isfinite(lp)):
            raise ValueError(
                "the model could not be solved anywhere on theta in "
                f"{target.theta(np.array([lo, hi]))}"
            )
        region = np.flatnonzero(lp > lp.max() - settings.tail)
        j0, j1 = max(region[0] - 1, 0), min(region[-1] + 1, xs.size - 1)
        lo, hi = float(xs[j0]), float(xs[j1])
        if region.size >= 8 or zooms >= 20:
            break
        zooms += 1
    xs = np.linspace(lo, hi, settings.points)
    lp = target(xs[:, None])
    top = float(lp.max())
    w = np.exp(lp - top)
    z = scipy.integrate.trapezoid(w, xs)
    pdf_xi = w / z
    theta = target.theta(xs)
    mean = scipy.integrate.trapezoid(theta * pdf_xi, xs)
    var = scipy.integrate.trapezoid((theta - mean) ** 2 * pdf_xi, xs)
    q_xi = _quantiles(xs, pdf_xi, LEVELS)
    dens = pdf_xi / theta if target.transform == "log" else pdf_xi
    mode = _parabolic_peak(theta, dens)
    edge_drop = top - max(float(lp[0]), float(lp[-1]))
    half = top - settings.tail / 2
    cut = (lo <= lo0 and lp[0] > half and not at_lower) or (
        hi >= hi0 and lp[-1] > half and not at_upper
    )
    resolved = np.sum(lp > top - 5.0) >= 5
    return Posterior(
        names=tuple(model.parameters.names),
        method="grid",
        mean=np.array([mean]),
        std=np.array([math.sqrt(max(var, 0.0))]),
        quantiles=target.theta(q_xi)[:, None],
        levels=LEVELS,
        map=np.array([mode]),
        converged=bool(resolved and not cut),
        n_solves=(model.cost() - cost0).forward_solves,
        grid=theta,
        density=dens,
        diagnostics={
            "edge_drop": edge_drop,
            "zooms": float(zooms),
            "failed": float(target.failed),
        },
    )


def _quantiles(x: FloatArray, f: FloatArray, levels: Sequence[float]) -> FloatArray:
    """Quantiles of the piecewise-linear density f on x (normalised here).

    In the interval [x_i, x_i + h] the cumulative is F_i + f_i t + (f_{i+1} -
    f_i) t^2 / (2h), inverted exactly (the cumulative trapezoid's own model).
    """
    cdf = scipy.integrate.cumulative_trapezoid(f, x, initial=0.0)
    total = cdf[-1]
    out = np.empty(len(levels))
    for j, q in enumerate(levels):
        target = q * total
        i = int(np.clip(np.searchsorted(cdf, target) - 1, 0, x.size - 2))
        h = x[i + 1] - x[i]
        a, b, c = (f[i + 1] - f[i]) / (2 * h), f[i], cdf[i] - target
        den = b + math.sqrt(max(b * b - 4 * a * c, 0.0))  # the stable root
        t = -2 * c / den if den > 0 else 0.0
        out[j] = x[i] + min(max(t, 0.0), h)
    return out


def model_error(
    model: ForwardModel,
    theta: FloatArray,
    observations: Sequence[Observation | None],
) -> float:
    r"""Std of the model's misfit beyond the observation noise, per component.

    The coarse-vs-fine misfit at the best constant parameters theta (e.g. E_ref
    fitted to noise-free truth observations of a calibration load path):

    .. math::

        e^2 = \max\Big(0, \frac{1}{N} \sum_{k \text{ observed}}
        \lVert y_k - h(u_k(\theta)) \rVert^2 - \bar\sigma^2\Big),

    N the number of observed components and sigma-bar^2 the mean noise
    variance of the observations. One path simulation.
    """
    obs = {i: o for i, o in enumerate(observations, start=1) if o is not None}
    if not obs:
        raise ValueError("no observations to measure a misfit on")
    theta = np.atleast_1d(np.asarray(theta, dtype=float))
    u = np.asarray(model.reset(), dtype=float)
    sq, n, noise = 0.0, 0, 0.0
    for k in range(1, max(obs) + 1):
        u = np.asarray(model.step(theta, k, u), dtype=float)
        if k in obs:
            y = np.asarray(obs[k].values, dtype=float)
            sq += float(np.sum((y - np.asarray(model.observe(u), dtype=float)) ** 2))
            n += y.size
            var = np.asarray(obs[k].noise_std, dtype=float) ** 2
            noise += float(np.sum(np.broadcast_to(var, y.shape)))
    return math.sqrt(max(0.0, (sq - noise) / n))


def _parabolic_peak(x: FloatArray, f: FloatArray) -> float:
    """Abscissa of the vertex of the parabola through the largest f and neighbours."""
    i = int(np.argmax(f))
    if i == 0 or i == x.size - 1:
        return float(x[i])
    xs, fs = x[i - 1 : i + 2], f[i - 1 : i + 2]
    a, b, _ = np.polyfit(xs - x[i], fs / fs[1], 2)
    return float(x[i] - b / (2 * a)) if a < 0 else float(x[i])


def mcmc_posterior(
    model: ForwardModel,
    prior: Prior,
    observations: Sequence[Observation | None],
    settings: PosteriorSettings | None = None,
) -> Posterior:
    """The posterior by adaptive random-walk Metropolis in xi (any p).

    1. MAP: :func:`scipy.optimize.least_squares` on the whitened residuals
       [(y_k - h_k) / sqrt(r_k); (xi - mu) / sd] from the prior mean (at most
       30 (p + 1) paths); Laplace covariance C = (J^T J)^-1.
    2. ``chains`` chains from MAP + 2 C^{1/2} z; proposal N(0, s^2 C) with
       s = 2.38 / sqrt(p); during ``warmup`` every 50 iterations s is scaled
       by exp(acceptance - 0.25) and C is re-estimated from the pooled recent
       draws; then fixed for ``samples`` kept iterations.
    3. Split R-hat per parameter across chains and the integrated
       autocorrelation time tau (Sokal's window, c = 5, on the chain-averaged
       autocorrelation): converged when R-hat < ``rhat_max`` and
       samples > ``tau_factor`` tau.
    """
    settings = settings or PosteriorSettings()
    target = _Target(model, prior, observations, settings)
    p = model.parameters.p
    n_opt = 30 * (p + 1)
    n_chain = settings.chains * (settings.warmup + settings.samples)
    need = target.cost(n_opt + n_chain)
    if need > settings.max_solves:
        raise ValueError(
            f"max_solves = {settings.max_solves} cannot hold {settings.chains} "
            f"chains of {settings.warmup} + {settings.samples} iterations and the "
            f"MAP search ({need} solves on this path)"
        )
    cost0 = model.cost()
    rng = np.random.default_rng(settings.seed)
    xi_map, cov = _map_and_laplace(target, n_opt)
    chains = _metropolis(target, xi_map, cov, rng, settings)  # (c, n, p)
    rhat = _split_rhat(chains)
    tau = np.array([_autocorr_time(chains[:, :, j]) for j in range(p)])
    n = chains.shape[1]
    converged = bool(
        np.all(rhat < settings.rhat_max) and np.all(n > settings.tau_factor * tau)
    )
    if not converged:
        log.warning(
            "MCMC posterior not converged: R-hat %s, tau %s for %d samples a chain",
            np.round(rhat, 3),
            np.round(tau, 1),
            n,
        )
    samples = target.theta(chains.reshape(-1, p))
    return Posterior(
        names=tuple(model.parameters.names),
        method="mcmc",
        mean=samples.mean(axis=0),
        std=samples.std(axis=0, ddof=1),
        quantiles=np.quantile(samples, LEVELS, axis=0),
        levels=LEVELS,
        map=target.theta(xi_map),
        converged=converged,
        n_solves=(model.cost() - cost0).forward_solves,
        samples=samples,
        diagnostics={
            "rhat_max": float(rhat.max()),
            "tau_max": float(tau.max()),
            "ess_min": float(chains.shape[0] * n / tau.max()),
            "acceptance": float(_acceptance(chains)),
            "failed": float(target.failed),
        },
    )


def _map_and_laplace(target: _Target, max_paths: int) -> tuple[FloatArray, FloatArray]:
    """MAP of xi by least squares from the prior mean; Laplace covariance."""
    sd = np.sqrt(target.var)
    paths = 0

    def residuals(xi: FloatArray) -> FloatArray:
        nonlocal paths
        paths += 1
        theta = target.theta(xi)[None, :]
        if not (
            np.all(np.isfinite(theta))
            and np.all(theta > target.lower)
            and np.all(theta < target.upper)
        ):
            raise _OutOfBounds
        need = target.cost(1)
        if target.used + need > target.budget:
            raise ValueError(f"max_solves = {target.budget} is exhausted")
        target.used += need
        model = target.model
        u = np.asarray(model.reset(), dtype=float)
        res = [(xi - target.mu) / sd]
        for k in range(1, target.last + 1):
            new, ok = _step_all(model, theta, k, u[None, :])
            if not ok[0]:
                raise _OutOfBounds
            u = new[0]
            if k in target.obs:
                y, r = target.obs[k]
                res.append((y - np.asarray(model.observe(u), dtype=float)) / np.sqrt(r))
        return np.concatenate(res)

    lo, hi = target.xi_bounds()
    x0 = np.clip(target.mu, lo + 1e-6 * np.abs(lo) + 1e-12, hi - 1e-6 * np.abs(hi))
    try:
        sol = scipy.optimize.least_squares(
            residuals,
            x0,
            x_scale=sd,
            bounds=(lo, hi),
            max_nfev=max(max_paths // (target.mu.size + 1), 2),
            diff_step=1e-6,
        )
        xi_map, jac = sol.x, sol.jac
    except _OutOfBounds:
        log.warning("MAP search left the model's bounds; starting from the prior")
        return target.mu.copy(), np.diag(target.var)
    try:
        cov = np.linalg.inv(jac.T @ jac)
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        cov = np.diag(target.var)
    return xi_map, 0.5 * (cov + cov.T)


class _OutOfBounds(Exception):
    """The MAP search stepped where the model has no solution."""


def _metropolis(
    target: _Target,
    start: FloatArray,
    cov: FloatArray,
    rng: np.random.Generator,
    settings: PosteriorSettings,
) -> FloatArray:
    """Adaptive (warm-up only) random-walk Metropolis; kept draws (c, n, p)."""
    p = start.size
    c = settings.chains
    chol = np.linalg.cholesky(cov)
    x = start[None, :] + 2.0 * rng.standard_normal((c, p)) @ chol.T
    lp = target(x)
    for _ in range(100):  # an over-dispersed start must have positive density
        bad = ~np.isfinite(lp)
        if not bad.any():
            break
        x[bad] = start + rng.standard_normal((int(bad.sum()), p)) @ chol.T
        lp[bad] = target(x[bad])
    scale = 2.38 / math.sqrt(p)
    total = settings.warmup + settings.samples
    kept = np.empty((c, settings.samples, p))
    recent: list[FloatArray] = []
    accepted = np.zeros(c)
    for it in range(total):
        prop = x + scale * rng.standard_normal((c, p)) @ chol.T
        lq = target(prop)
        accept = np.log(rng.uniform(size=c)) < lq - lp
        x[accept], lp[accept] = prop[accept], lq[accept]
        if it < settings.warmup:
            accepted += accept
            recent.append(x.copy())
            if (it + 1) % 50 == 0:
                rate = float(accepted.mean() / 50)
                scale *= math.exp(rate - 0.25)
                pooled = np.concatenate(recent[-200:])
                emp = np.atleast_2d(np.cov(pooled, rowvar=False))
                try:
                    chol = np.linalg.cholesky(emp + 1e-12 * np.trace(emp) * np.eye(p))
                except np.linalg.LinAlgError:
                    pass
                accepted[:] = 0
        else:
            kept[:, it - settings.warmup] = x
    return kept


def _split_rhat(chains: FloatArray) -> FloatArray:
    """Split R-hat (Gelman et al. 2013) per parameter of chains (c, n, p)."""
    n = chains.shape[1]
    half = n // 2
    split = np.concatenate([chains[:, :half], chains[:, half : 2 * half]], axis=0)
    m = split.shape[1]
    means = split.mean(axis=1)  # (2c, p)
    within = split.var(axis=1, ddof=1).mean(axis=0)
    between = m * means.var(axis=0, ddof=1)
    var = (m - 1) / m * within + between / m
    with np.errstate(divide="ignore", invalid="ignore"):
        rhat = np.sqrt(var / within)
    return np.where(within > 0, rhat, np.inf)


def _autocorr_time(x: FloatArray, c: float = 5.0) -> float:
    """Integrated autocorrelation time of chains x (chains, n), Sokal's window.

    The autocorrelation is averaged over chains (as emcee does) and summed up to
    the first window M with M >= c tau(M).
    """
    n = x.shape[1]
    f = np.zeros(n)
    for row in x:
        d = row - row.mean()
        spec = np.fft.rfft(d, n=2 * n)
        acf = np.fft.irfft(spec * np.conjugate(spec))[:n]
        if acf[0] > 0:
            f += acf / acf[0]
    if not np.any(f):
        return float("inf")
    f /= x.shape[0]
    taus = 2.0 * np.cumsum(f) - 1.0
    window = np.arange(n) >= c * taus
    m = int(np.argmax(window)) if window.any() else n - 1
    return float(taus[m])


def _acceptance(chains: FloatArray) -> float:
    """Fraction of kept iterations where a chain moved."""
    moved = np.any(np.diff(chains, axis=1) != 0, axis=2)
    return float(moved.mean())

r"""The density both posterior methods explore: prior times path likelihood.

:class:`LogPosterior` is the log posterior density of xi (the filters'
transform of theta, :mod:`idbench.estimate.transforms`) for a batch of points; each
evaluation simulates the whole load path once per point (``reset``, ``step``,
``observe`` of the :class:`~idbench.ForwardModel` protocol, ``step_many`` when
the model has it), and counts the solves against ``max_solves``.
:func:`model_error` is the misfit of one such path beyond the noise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from idbench.core.capabilities import step_many_of
from idbench.core.interfaces import (
    FloatArray,
    ForwardModel,
    ModelFailure,
    Observation,
    Prior,
)
from idbench.estimate.posterior.settings import PosteriorSettings
from idbench.estimate.transforms import TRANSFORMS

RETRY_SUBSTEPS = 4
"""A step that fails is retried alone, then once more in this many sub-steps."""


class LogPosterior:
    """Log posterior density of xi for a batch of points; counts the budget.

    Parameters
    ----------
    model
        The forward model (its parameters' bounds truncate the density).
    prior
        The run's prior in natural units, mapped to xi by the transform.
    observations
        Entry k-1 is step k's observation or None; R_k = max(sigma_k, floor)^2.
        NaN (occluded) values are left out of the likelihood (:meth:`seen`).
    settings
        ``transform``, ``sigma_floor`` and ``max_solves`` are used.

    Raises
    ------
    ValueError
        A prior of the wrong length (or non-positive under the log transform),
        more observations than steps, an observation out of place, or none.
    """

    def __init__(
        self,
        model: ForwardModel,
        prior: Prior,
        observations: Sequence[Observation | None],
        settings: PosteriorSettings,
    ) -> None:
        self.model = model
        self.transform = TRANSFORMS[settings.transform]
        mu, cov = self.transform.prior_xi(prior, model.parameters.p)
        self.mu, self.var = mu, np.diag(cov).copy()
        if len(observations) > model.n_steps:
            raise ValueError(
                f"{len(observations)} observations for a model of {model.n_steps} steps"
            )
        self.obs: dict[int, tuple[FloatArray, float | FloatArray]] = {}
        self.masks: dict[int, np.ndarray] = {}  # visible values, if some are NaN
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
            y = np.asarray(o.values, dtype=float)
            mask = ~np.isnan(y)
            if not mask.all():  # occluded values: the visible ones only
                if not mask.any():
                    continue  # every value occluded: no observation
                self.masks[i] = mask
                y = y[mask]
                r = r if np.ndim(r) == 0 else np.asarray(r)[mask]
            self.obs[i] = (y, r)
        if not self.obs:
            raise ValueError("no observations: the posterior is the prior")
        self.last = max(self.obs)
        self.lower = np.asarray(model.parameters.lower, dtype=float)
        self.upper = np.asarray(model.parameters.upper, dtype=float)
        self.budget = settings.max_solves
        self.used = 0
        self.failed = 0

    def seen(self, k: int, h: FloatArray) -> FloatArray:
        """The predicted observation ``h`` of step k at its visible values."""
        mask = self.masks.get(k)
        return h if mask is None else h[mask]

    def theta(self, xi: FloatArray) -> FloatArray:
        """Natural parameters of xi (any shape)."""
        return self.transform.to_theta(xi)

    def xi_bounds(self) -> tuple[FloatArray, FloatArray]:
        """The model's bounds in xi (-inf for a lower bound <= 0 under the log)."""
        lo = self.transform.to_xi(self.lower)  # the log of a negative bound is NaN
        return np.where(np.isnan(lo), -np.inf, lo), self.transform.to_xi(self.upper)

    def inside(self, theta: FloatArray) -> np.ndarray:
        """Mask (B,) of the rows of theta (B, p) strictly inside the bounds."""
        return np.all(
            np.isfinite(theta) & (theta > self.lower) & (theta < self.upper), axis=1
        )

    def cost(self, n_paths: int) -> int:
        """Solves of ``n_paths`` path simulations."""
        return n_paths * self.last

    def charge(self, n_paths: int) -> None:
        """Count ``n_paths`` path simulations; ValueError if the budget is spent."""
        need = self.cost(n_paths)
        if self.used + need > self.budget:
            raise ValueError(
                f"max_solves = {self.budget} is exhausted ({self.used} used, "
                f"{need} more needed)"
            )
        self.used += need

    def log_prior(self, xi: FloatArray) -> FloatArray:
        """Log prior density of xi (B, p) -> (B,), up to a constant."""
        return -0.5 * np.sum((xi - self.mu) ** 2 / self.var, axis=1)

    def __call__(self, xi: FloatArray) -> FloatArray:
        """Log posterior (B,) of xi (B, p), up to a constant; -inf if unsolvable."""
        xi = np.atleast_2d(np.asarray(xi, dtype=float))
        theta = self.theta(xi)
        out = np.full(xi.shape[0], -np.inf)
        idx = np.flatnonzero(self.inside(theta))
        if idx.size == 0:
            return out
        self.charge(idx.size)
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
            new, ok = advance_batch(model, thetas[idx], k, states[idx])
            states[idx] = new
            alive[idx[~ok]] = False
            if k in self.obs:
                y, r = self.obs[k]
                for i in np.flatnonzero(alive):
                    h = self.seen(k, np.asarray(model.observe(states[i]), float))
                    if np.ndim(r) == 0:
                        ll[i] -= 0.5 * float(np.sum((y - h) ** 2)) / r
                    else:  # one variance per value
                        ll[i] -= 0.5 * float(np.sum((y - h) ** 2 / r))
        self.failed += int(np.sum(~alive))
        ll[~alive] = -np.inf
        return ll


def advance_batch(
    model: ForwardModel, thetas: FloatArray, k: int, states: FloatArray
) -> tuple[FloatArray, np.ndarray]:
    """Advance a batch one step; (new states, solved mask).

    ``model.step_many`` when present, then each failed member alone, once more
    in :data:`RETRY_SUBSTEPS` sub-steps.
    """
    new = np.array(states, dtype=float)
    ok = np.zeros(states.shape[0], dtype=bool)
    step_many = step_many_of(model)
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

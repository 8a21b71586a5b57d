r"""Shared machinery of the ensemble filters (EnKF, ETKF).

The ensemble has N members x_i = [u_i; xi_i] (rows of X, shape (N, n)). At
:meth:`EnsembleFilter.start` every u_i is the unloaded state and the xi_i are
drawn from the prior N(mu_xi, P_xi) with the filter's own seeded
:class:`numpy.random.Generator`. With ``init = "exact"`` (default) the draws
are centred and whitened so that the sample mean and the sample covariance
(divisor N - 1) equal mu_xi and P_xi exactly (needs N >= p + 1); ``"random"``
keeps the plain draws. Each step:

1. forecast: every member advances one load step with its own parameters,
   u_i <- M_k(theta(xi_i), u_i) (N forward solves; one ``model.step_many``
   call when the model has it);
2. with an observation y: the analysis of the subclass (perturbed
   observations or square root) on the joint state, then multiplicative
   inflation of the anomalies, x_i <- xbar + rho (x_i - xbar), rho >= 1;
3. report the sample mean of xi and its sample covariance (divisor N - 1).

The innovation of the last observed step, nu = y - mean_i h(u_i) and its
forecast covariance S = cov_i h(u_i) + R, is kept in :attr:`innovation` for
the normalised innovation squared nu^T S^-1 nu.

With ``correction = "approximation-error"`` (:class:`idbench.Filter`) each
h(u_i) is the corrected model's (plus the calibrated mean discrepancy) and
the noise is R + Sigma, Sigma at the forecast mean state: the analysis runs
on observations whitened by the lower Cholesky factor C of R + Sigma
(y <- C^-1 y, h <- C^-1 h, R <- I), which for a Gaussian update is the same
as using R + Sigma (for the EnKF the perturbations become N(0, R + Sigma)).
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass

import numpy as np

from idbench import Analysis, Filter, ForwardModel, Observation, Prior, noise_matrix
from idbench_filters.common import (
    FloatArray,
    advance_many,
    check_choice,
    check_positive,
)

INITS = ("exact", "random")


def draw_prior(
    rng: np.random.Generator,
    mean: FloatArray,
    cov: FloatArray,
    n_members: int,
    exact: bool,
) -> FloatArray:
    """N draws (N, p) of N(mean, cov); with ``exact`` their sample moments match.

    Exact moments: Z (N, p) standard normal, centred, then Z <- Z C^-T with C
    the lower Cholesky factor of Z^T Z / (N - 1), so Z^T Z / (N - 1) = I_p;
    the draws are mean + Z chol(cov)^T.
    """
    p = mean.size
    z = rng.standard_normal((n_members, p))
    if exact:
        if n_members < p + 1:
            raise ValueError(
                f"members = {n_members} is too few for init = 'exact' with "
                f"p = {p} parameters; use members >= {p + 1} or init = 'random'"
            )
        z -= z.mean(axis=0)
        c = np.linalg.cholesky(z.T @ z / (n_members - 1))
        z = np.linalg.solve(c, z.T).T
    return mean[None, :] + z @ np.linalg.cholesky(cov).T


@dataclass
class EnsembleFilter(Filter, abstract=True):
    """Base of the ensemble filters: settings, start, forecast and reporting.

    Attributes
    ----------
    members
        Ensemble size N >= 2; None (default) means 2p + 2.
    inflation
        Multiplicative inflation rho >= 1 of the anomalies after each analysis;
        1 (default) is none.
    init
        ``"exact"`` (default): the initial draws have exactly the prior's mean
        and covariance (needs N >= p + 1); ``"random"``: plain draws.
    seed
        Seed of the filter's :class:`numpy.random.Generator` (initial draws and,
        for the EnKF, observation perturbations).
    """

    members: int | None = None
    inflation: float = 1.0
    init: str = "exact"
    seed: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        n = self.members
        if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 2):
            raise ValueError(
                f"members = {n!r} is not allowed; an ensemble needs an integer "
                ">= 2 members"
            )
        check_positive("inflation", self.inflation)
        if self.inflation < 1:
            raise ValueError(
                f"inflation = {self.inflation!r} is not allowed; it must be >= 1 "
                "(1 = no inflation)"
            )
        check_choice("init", self.init, INITS)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int):
            raise ValueError(f"seed = {self.seed!r} is not allowed; use an integer")
        if self.seed < 0:
            raise ValueError(f"seed = {self.seed!r} is not allowed; it must be >= 0")

    def estimate_solves(self, n_state: int, p: int, steps: int) -> int:
        """One forward step per member and load step."""
        return (self.members if self.members is not None else 2 * p + 2) * steps

    def begin(self, model: ForwardModel, prior: Prior) -> None:
        """Begin a run: u_i = reset(), xi_i drawn from the prior (see ``init``)."""
        p = model.parameters.p
        n_members = self.members if self.members is not None else 2 * p + 2
        mu, p_xi = self.prior_xi(prior)
        u0 = np.asarray(model.reset(), dtype=float)
        self._rng = np.random.default_rng(self.seed)
        xi = draw_prior(self._rng, mu, p_xi, n_members, self.init == "exact")
        self._nu = u0.size
        self._X = np.hstack([np.tile(u0, (n_members, 1)), xi])

    @property
    def solves_per_step(self) -> int:
        """Forward solves a step: N."""
        self.run  # noqa: B018 (RuntimeError before start())
        return int(self._X.shape[0])

    @property
    def ensemble(self) -> FloatArray:
        """The current members (N, n), rows [u_i; xi_i] (a copy)."""
        return self._X.copy()

    @abstractmethod
    def analysis(
        self, X: FloatArray, HX: FloatArray, y: FloatArray, r: float
    ) -> FloatArray:
        """Analysis ensemble (N, n) from the forecast X, HX (N, m), y and R = r I."""
        raise NotImplementedError

    def assimilate(self, k: int, observation: Observation | None) -> Analysis:
        """Forecast every member to step k, then assimilate the observation."""
        model = self.model
        nu = self._nu
        X = self._X.copy()
        thetas = np.stack([self.to_theta(x) for x in X[:, nu:]])
        X[:, :nu] = advance_many(model, thetas, k, X[:, :nu])
        if observation is not None:
            y = np.asarray(observation.values, dtype=float)
            HX = np.stack([model.observe(x) for x in X[:, :nu]]).astype(float)
            r = self.noise_var(observation)
            sigma = self.extra_cov(X[:, :nu].mean(axis=0))
            cov_hx = np.atleast_2d(np.cov(HX, rowvar=False))
            R = noise_matrix(r, y.size)
            if sigma is None:
                self.innovation = (y - HX.mean(axis=0), cov_hx + R)
                X = self.analysis(X, HX, y, r)
            else:  # corrected model: whiten by chol(R + Sigma), then R = I
                c = np.linalg.cholesky(R + sigma)
                self.innovation = (y - HX.mean(axis=0), cov_hx + c @ c.T)
                yw = np.linalg.solve(c, y)
                hxw = np.linalg.solve(c, HX.T).T
                X = self.analysis(X, hxw, yw, 1.0)
            if self.inflation > 1:
                xbar = X.mean(axis=0)
                X = xbar + self.inflation * (X - xbar)
        xbar = X.mean(axis=0)
        cov_xi = np.atleast_2d(np.cov(X[:, nu:], rowvar=False))
        self._X = X
        return Analysis(xbar[nu:], cov_xi, xbar[:nu], finite=(cov_xi, X))

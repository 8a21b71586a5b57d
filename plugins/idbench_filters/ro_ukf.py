"""Reduced-order unscented Kalman filter (Moireau & Chapelle 2011).

The state is x = [u; xi] (u the model state, xi the transformed parameters,
n = len(u) + p). Its covariance is kept factored as P = L U^-1 L^T with
L (n, p) and U (p, p), so only p directions are ever uncertain: the
displacements are slaved to the parameters, as in Verdandi and SOFA's Optimus.

Sigma directions I* (p, r) with weights alpha = 1/r are scaled so that
sum_i alpha I*_i = 0 and sum_i alpha I*_i I*_i^T = I_p: ``"simplex"``
(r = p + 1, the rows of a Helmert matrix times sqrt(r); +-1 for p = 1) or
``"star"`` (r = 2p + 1: 0 and +-sqrt((2p + 1)/2) e_j). One step:

0. random walk (optional): U^-1 <- U^-1 + L_xi^-1 Q L_xi^-T, Q = q^2 I_p;
1. C = chol(U^-1) (lower), L <- L C, x_i = x + L I*_i;
2. advance each x_i one load step with the model (r forward solves, batched
   through the model's ``step_many`` when it has one);
3. x <- sum_i alpha x_i, L <- alpha X I*^T, U <- I;
4. with an observation y: Z_i = y - h(x_i), zbar = sum_i alpha Z_i,
   G = alpha I* Z^T (p, m), U <- I + G R^-1 G^T,
   x <- x - L U^-1 G R^-1 zbar;
5. report P_xi = L_xi U^-1 L_xi^T.

After an observed step :attr:`RoUkf.innovation` is (zbar, S), the mean
innovation and its forecast covariance S = sum_i alpha (Z_i - zbar)
(Z_i - zbar)^T + R, for the normalised innovation squared zbar^T S^-1 zbar.

For a linear-Gaussian model this is exactly the Kalman filter.

Model-error-aware variant (``model_error`` = e > 0): the coarse model's own
misfit is treated as extra observation noise, R = (max(sigma, floor)^2 + e^2) I,
with e the RMS coarse-vs-fine marker misfit at the best constant parameters
(e.g. from a calibration against the truth mesh). It widens the reported
uncertainty; it cannot remove the bias of the mean.

Corrected variant (``correction = "approximation-error"``, see
:class:`idbench.Filter` and :mod:`idbench.calibrate.discrepancy`): the model's
``observe`` already adds the calibrated mean discrepancy mu(h(x_i)) to each
sigma point's observation, and R becomes the full matrix
R = (max(sigma, floor)^2 + e^2) I + Sigma(h(x)) at the forecast mean x, in
U <- I + G R^-1 G^T and x <- x - L U^-1 G R^-1 zbar. The cost of a step is
unchanged but for one m x m solve.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from idbench import (
    Analysis,
    Filter,
    ForwardModel,
    LowRankCovariance,
    Observation,
    Prior,
    noise_matrix,
)
from idbench_filters.common import (
    FloatArray,
    advance_many,
    check_choice,
    check_positive,
)

SIGMA_POINTS = ("simplex", "star")

DENSE_INNOVATION = 512
"""Observations of more values (a point cloud) report their innovation
covariance as a :class:`idbench.LowRankCovariance` (R + alpha dz dz^T, the
NIS by Woodbury) instead of forming the (m, m) matrix."""


def sigma_directions(p: int, kind: str) -> FloatArray:
    """Normalised sigma directions I* (p, r).

    ``sum_i I*_i / r = 0`` and ``sum_i I*_i I*_i^T / r = I_p``.
    """
    check_choice("sigma_points", kind, SIGMA_POINTS)
    if kind == "simplex":
        r = p + 1
        return np.sqrt(r) * scipy.linalg.helmert(r)
    r = 2 * p + 1
    s = np.sqrt(r / 2.0)
    return np.hstack([np.zeros((p, 1)), s * np.eye(p), -s * np.eye(p)])


@dataclass
class RoUkf(Filter):
    """Reduced-order UKF on [state; xi] with a rank-p factored covariance.

    Attributes
    ----------
    sigma_points
        ``"simplex"`` (p + 1 solves a step, default) or ``"star"`` (2p + 1).
    param_noise
        Std q of a random walk on xi per step (Q = q^2 I_p); 0 (default) keeps
        the parameters constant, as the reference implementations do.
    model_error
        Std e (observation units, m) of the model's discretisation error, added
        to the noise variance: R = (max(sigma, sigma_floor)^2 + e^2) I; 0
        (default) trusts the model.
    """

    sigma_points: str = "simplex"
    param_noise: float = 0.0
    model_error: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check_choice("sigma_points", self.sigma_points, SIGMA_POINTS)
        check_positive("param_noise", self.param_noise, allow_zero=True)
        check_positive("model_error", self.model_error, allow_zero=True)

    def begin(self, model: ForwardModel, prior: Prior) -> None:
        """Begin a run: x = [reset(); mu_xi], L = [0; I_p], U = P_xi^-1."""
        p = model.parameters.p
        mu, p_xi = self.prior_xi(prior)
        u0 = np.asarray(model.reset(), dtype=float)
        self._nu = u0.size
        self._x = np.concatenate([u0, mu])
        self._L = np.vstack([np.zeros((self._nu, p)), np.eye(p)])
        self._Uinv = p_xi.copy()  # U^-1, kept as the inverse: that is what is sampled
        self._I = sigma_directions(p, self.sigma_points)

    def estimate_solves(self, n_state: int, p: int, steps: int) -> int:
        """One forward step per sigma point and load step."""
        return sigma_directions(p, self.sigma_points).shape[1] * steps

    @property
    def solves_per_step(self) -> int:
        """Forward solves a step: r = p + 1 (simplex) or 2p + 1 (star)."""
        self.run  # noqa: B018 (RuntimeError before start())
        return int(self._I.shape[1])

    def assimilate(self, k: int, observation: Observation | None) -> Analysis:
        """Forecast to step k with r sigma points, then assimilate the observation."""
        model = self.model
        nu = self._nu
        I = self._I  # noqa: E741
        r = I.shape[1]
        alpha = 1.0 / r
        uinv = self._Uinv
        if self.param_noise > 0:
            m = np.linalg.solve(self._L[nu:], self.param_noise * np.eye(I.shape[0]))
            uinv = uinv + m @ m.T
        c = np.linalg.cholesky(0.5 * (uinv + uinv.T))
        L = self._L @ c
        # sigma points as rows (r, n): each state handed to the model is
        # contiguous (a strided column view makes the solves ~20% slower)
        X = self._x[None, :] + (L @ I).T
        thetas = np.stack([self.to_theta(X[i, nu:]) for i in range(r)])
        X[:, :nu] = advance_many(model, thetas, k, X[:, :nu])
        x = alpha * X.sum(axis=0)
        L = alpha * X.T @ I.T
        uinv = np.eye(I.shape[0])
        if observation is not None:
            y = np.asarray(observation.values, dtype=float)
            hx = np.stack([model.observe(X[i, :nu]) for i in range(r)], axis=1)
            Z = y[:, None] - hx  # (m, r)
            zbar = Z @ np.full(r, alpha)
            G = alpha * I @ Z.T  # (p, m)
            var = self.noise_var(observation) + self.model_error**2
            dz = Z - zbar[:, None]
            sigma = self.extra_cov(x[:nu])
            if sigma is None:
                if y.size <= DENSE_INNOVATION:
                    S = alpha * dz @ dz.T + noise_matrix(var, y.size)
                    self.innovation = (zbar, S)
                else:  # a point cloud: S = R + alpha dz dz^T, never formed
                    diag = np.broadcast_to(np.asarray(var, dtype=float), (y.size,))
                    low = LowRankCovariance(diag.copy(), np.sqrt(alpha) * dz)
                    self.innovation = (zbar, low)
                rinv = 1.0 / var
                if np.ndim(rinv) == 0:
                    U = np.eye(I.shape[0]) + rinv * (G @ G.T)
                    x = x - L @ np.linalg.solve(U, rinv * (G @ zbar))
                else:  # a diagonal R with one variance per value
                    U = np.eye(I.shape[0]) + (G * rinv) @ G.T
                    x = x - L @ np.linalg.solve(U, G @ (rinv * zbar))
            else:  # corrected model: R + Sigma at the forecast mean
                R = noise_matrix(var, y.size) + sigma
                self.innovation = (zbar, alpha * dz @ dz.T + R)
                rg = np.linalg.solve(R, np.column_stack([G.T, zbar]))
                U = np.eye(I.shape[0]) + G @ rg[:, :-1]
                x = x - L @ np.linalg.solve(U, G @ rg[:, -1])
            uinv = np.linalg.inv(U)
            uinv = 0.5 * (uinv + uinv.T)
        p_xi = L[nu:] @ uinv @ L[nu:].T
        self._x, self._L, self._Uinv = x, L, uinv
        return Analysis(x[nu:], p_xi, x[:nu], finite=(p_xi, x[:nu]))

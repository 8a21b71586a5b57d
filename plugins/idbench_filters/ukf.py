"""Full unscented Kalman filter on the augmented state [u; xi].

Built on filterpy's :class:`~filterpy.kalman.UnscentedKalmanFilter` with
:class:`~filterpy.kalman.MerweScaledSigmaPoints` (tested with filterpy 2.0.0).
The covariance P is a full (n, n) matrix, n = len(u) + p, so every step costs
2n + 1 forward solves: this is the joint estimation that becomes infeasible on
fine meshes, kept for small ones and as a cross-check of the RO-UKF.

Sigma points chi = x +- sqrt((n + lambda) P) with
lambda = alpha^2 (n + kappa) - n. The matrix square root symmetrises P and
clips its eigenvalues from below, S = diag(sqrt(max(w, eps w_max))) V^T with
P = V diag(w) V^T and S^T S ~ P (filterpy takes the rows of S), so a
rank-deficient P (the displacements start exactly known) still samples.
The process noise is zero: u_k is a function of theta and the warm start.
The sigma points are advanced in one call of the model's ``step_many`` when it
has one (shared factorizations; see :class:`idbench.BatchModel`), else one
``step`` each, as filterpy's own ``fx`` loop would. With ``correction =
"approximation-error"`` (:class:`idbench.Filter`) h is the corrected model's
and R the matrix R + Sigma at the forecast mean. An occluded observation
(NaN entries) is updated with its visible entries only (:class:`idbench.Filter`
masks h and R). The innovation (filterpy's y and S of the update) is kept
for the normalized innovation squared (NIS).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from filterpy.kalman import (
    MerweScaledSigmaPoints,
    UnscentedKalmanFilter,
    unscented_transform,
)

from idbench import (
    Analysis,
    Filter,
    ForwardModel,
    Observation,
    Prior,
    Skipped,
    noise_matrix,
)
from idbench_filters.common import FloatArray, advance, advance_many, check_positive

EIG_FLOOR = 1e-14  # relative eigenvalue floor of the sampled square root


class _BatchedUkf(UnscentedKalmanFilter):  # type: ignore[misc]
    """filterpy's UKF with the sigma points advanced in one call.

    ``fx_many(sigmas (2n + 1, n), dt) -> (2n + 1, n)`` replaces filterpy's loop
    of ``fx`` over the sigma points (``compute_process_sigmas``); everything
    else, the unscented transform and the update included, is filterpy's.
    """

    def __init__(self, fx_many: Any, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._fx_many = fx_many

    def compute_process_sigmas(self, dt: float, fx: Any = None, **fx_args: Any) -> None:
        """Sigma points of (x, P), advanced together through ``fx_many``."""
        sigmas = self.points_fn.sigma_points(self.x, self.P)
        self.sigmas_f = np.asarray(self._fx_many(sigmas, dt), dtype=float)


def weighted_transform(
    sigmas: FloatArray,
    Wm: FloatArray,
    Wc: FloatArray,
    noise_cov: FloatArray | None = None,
    mean_fn: Any = None,
    residual_fn: Any = None,
) -> tuple[FloatArray, FloatArray]:
    """The unscented transform of filterpy for plain means and residuals, faster.

    The same sums, mean = Wm sigmas and P = sum_i Wc_i y_i y_i^T (+ noise), with
    y_i = sigma_i - mean; filterpy forms ``diag(Wc)`` as a dense (2n+1)^2
    matrix and multiplies by it, 3x the arithmetic of scaling the rows (and
    at n = 673 a 14 MB temporary). Means and residuals other than plain ones
    are left to filterpy.
    """
    if mean_fn is not None or residual_fn not in (None, np.subtract):
        return unscented_transform(sigmas, Wm, Wc, noise_cov, mean_fn, residual_fn)
    x = Wm @ sigmas
    y = sigmas - x
    P = (y.T * Wc) @ y
    if noise_cov is not None:
        P += noise_cov
    return x, P


def clipped_sqrt(P: FloatArray) -> FloatArray:
    """Row square root S of the symmetrised P with S^T S = P (eigenvalues clipped).

    Eigenvalues below ``EIG_FLOOR * max(w)`` are raised to it, so S has full rank.
    """
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    top = max(float(w.max()), np.finfo(float).tiny)
    w = np.maximum(w, EIG_FLOOR * top)
    return np.sqrt(w)[:, None] * V.T


@dataclass
class Ukf(Filter):
    """Full UKF (filterpy) on [state; xi] with a full covariance.

    Attributes
    ----------
    max_solves
        Budget of forward solves a step; :meth:`start` raises
        :class:`idbench.Skipped` when 2n + 1 exceeds it (default 1500: the
        240-node beam, 1,347 solves a step, runs; the 525-node one, 3,003,
        does not).
    max_parameters
        :meth:`start` raises :class:`idbench.Skipped` for more parameters
        (a field of cells: its 2n + 1 sigma points and dense covariance grow
        with them; use map-laplace or a localized ensemble filter).
    alpha, beta, kappa
        filterpy's scaled sigma point parameters (Van der Merwe): spread
        alpha sqrt(n + kappa) standard deviations; beta = 2 is optimal for
        Gaussians. The defaults (0.1, 2, 0) keep the log-modulus sigma points
        within about 1.7 standard deviations up to the budget.
    """

    max_solves: int = 1500
    max_parameters: int = 20
    alpha: float = 0.1
    beta: float = 2.0
    kappa: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (isinstance(self.max_parameters, int) and self.max_parameters >= 1):
            raise ValueError(
                f"max_parameters = {self.max_parameters!r} is not allowed; "
                "it must be an integer >= 1"
            )
        if not (isinstance(self.max_solves, int) and self.max_solves >= 1):
            raise ValueError(
                f"max_solves = {self.max_solves!r} is not allowed; "
                "it must be an integer >= 1"
            )
        check_positive("alpha", self.alpha)
        if self.alpha > 1:
            raise ValueError(
                f"alpha = {self.alpha!r} is not allowed; use 0 < alpha <= 1"
            )
        check_positive("beta", self.beta, allow_zero=True)
        if not np.isfinite(self.kappa):
            raise ValueError(
                f"kappa = {self.kappa!r} is not allowed; it must be finite"
            )

    def estimate_solves(self, n_state: int, p: int, steps: int) -> int:
        """2n + 1 forward steps a load step (n = n_state + p); 0 if skipped."""
        per_step = 2 * (n_state + p) + 1
        affordable = per_step <= self.max_solves and p <= self.max_parameters
        return per_step * steps if affordable else 0

    def begin(self, model: ForwardModel, prior: Prior) -> None:
        """Begin a run; raise Skipped if 2n + 1 solves a step exceed ``max_solves``."""
        p = model.parameters.p
        mu, p_xi = self.prior_xi(prior)
        u0 = np.asarray(model.reset(), dtype=float)
        n = u0.size + p
        if p > self.max_parameters:
            raise Skipped(
                f"full UKF skips a field of {p} parameters (over max_parameters = "
                f"{self.max_parameters}); use map-laplace or local-etkf"
            )
        if 2 * n + 1 > self.max_solves:
            raise Skipped(
                f"full UKF needs 2n+1 = {2 * n + 1} forward solves a step "
                f"(n = {u0.size} state + {p} parameters), over max_solves = "
                f"{self.max_solves}; use a coarser mesh or raise max_solves"
            )
        if n + self.kappa <= 0:
            raise ValueError(f"kappa = {self.kappa} needs n + kappa > 0 (n = {n})")
        self._nu = u0.size
        self._k = 0
        points = MerweScaledSigmaPoints(
            n,
            alpha=self.alpha,
            beta=self.beta,
            kappa=self.kappa,
            sqrt_method=clipped_sqrt,
        )
        self._dim_z = len(model.observe(u0))
        ukf = _BatchedUkf(
            fx_many=self._fx_many,
            dim_x=n,
            dim_z=self._dim_z,
            dt=1.0,
            hx=self._hx,
            fx=self._fx,
            points=points,
            sqrt_fn=clipped_sqrt,
        )
        ukf.x = np.concatenate([u0, mu])
        P = np.zeros((n, n))
        P[u0.size :, u0.size :] = p_xi
        ukf.P = P
        ukf.Q = np.zeros((n, n))
        self._ukf = ukf

    @property
    def solves_per_step(self) -> int:
        """Forward solves a step: 2n + 1."""
        return int(self._ukf.points_fn.num_sigmas())

    def _fx(self, x: FloatArray, dt: float) -> FloatArray:
        nu = self._nu
        theta = self.to_theta(x[nu:])
        u = advance(self.model, theta, self._k, x[:nu])
        return np.concatenate([u, x[nu:]])

    def _fx_many(self, sigmas: FloatArray, dt: float) -> FloatArray:
        nu = self._nu
        thetas = np.stack([self.to_theta(x[nu:]) for x in sigmas])
        out = np.array(sigmas, dtype=float)
        out[:, :nu] = advance_many(self.model, thetas, self._k, out[:, :nu])
        return out

    def _hx(self, x: FloatArray) -> FloatArray:
        return np.asarray(self.model.observe(x[: self._nu]), dtype=float)

    def assimilate(self, k: int, observation: Observation | None) -> Analysis:
        """Predict to step k (2n + 1 solves), then update with the observation."""
        ukf = self._ukf
        self._k = k
        ukf.predict(UT=weighted_transform)
        ukf.P = 0.5 * (ukf.P + ukf.P.T)
        if observation is not None:
            R: float | FloatArray = self.noise_var(observation)
            z = np.asarray(observation.values, dtype=float)
            sigma = self.extra_cov(ukf.x[: self._nu])
            if sigma is not None:  # corrected model: R + Sigma at the forecast mean
                R = self.noise_cov(observation, ukf.x[: self._nu])
            elif np.ndim(R) or z.size != self._dim_z:  # per value, or occluded
                R = noise_matrix(R, z.size)  # (filterpy expands a float to dim_z)
            ukf.update(z, R=R, UT=weighted_transform)
            ukf.P = 0.5 * (ukf.P + ukf.P.T)
            self.innovation = (np.array(ukf.y), np.array(ukf.S))  # the NIS
        nu = self._nu
        x, P = ukf.x, ukf.P
        return Analysis(x[nu:], P[nu:, nu:], x[:nu], finite=(P, x))

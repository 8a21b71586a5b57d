r"""Batch (weighted) least squares over the whole load path.

Finds the best constant parameter for all observations y_j seen so far,

.. math::

    \hat\xi = \arg\min_\xi \sum_j \| (y_j - h_j(\xi)) / \sigma_j \|^2,
    \qquad \sigma_j = \max(\text{noise\_std}_j, \text{sigma\_floor}),

with :func:`scipy.optimize.least_squares`. Every residual evaluation
re-simulates the path from ``reset()`` to the current step with theta(xi).
The Jacobian rows are -J_theta(u_j) diag(dtheta/dxi) / sigma_j from the model's
``sensitivity`` at each observed step's converged state (exact for a
path-independent, hyperelastic quasi-static problem: u_j depends on theta
only through the equilibrium of step j); without it, scipy's 2-point finite
differences, each column one more re-simulation. No prior term: the answer is
the "effective" parameter the harness uses as its reference. The reported std
is the Gauss-Newton one, sqrt(diag((J^T J)^-1)) at the optimum.

With ``correction = "approximation-error"`` (:class:`idbench.Filter`) h_j is
the corrected model's and each residual is whitened by the lower Cholesky
factor C_j of R + Sigma(h_j), r_j = C_j^-1 (y_j - h_j(xi)): Sigma is
evaluated at the states of the starting point and kept through a fit, then
once more at the first fit's states for a second fit (two passes).

An occluded observation (NaN entries, :class:`idbench.Filter`) keeps its
mask: its residuals, Jacobian rows and Sigma are those of its visible entries
at every later fit (:class:`idbench.MaskedModel`).

``refit="end"`` (default) fits once at the last step K and reports the prior
before; ``refit="each"`` refits, warm-started, at every observed step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import least_squares

from idbench import (
    Analysis,
    Diverged,
    Filter,
    ForwardModel,
    MaskedModel,
    Observation,
    Prior,
    sensitivity_of,
)
from idbench_filters.common import FloatArray, advance, check_choice, check_positive

REFITS = ("end", "each")
METHODS = ("trf", "dogbox")


TYPICAL_EVALUATIONS = 5
"""Path simulations a fit typically takes (for planning; ``max_nfev`` caps it)."""


@dataclass
class BatchLs(Filter):
    """Least squares over the whole path, re-simulated at every evaluation.

    Attributes
    ----------
    sigma_floor
        Lower bound (m) on the noise std that scales the residuals.
    refit
        ``"end"`` (one fit at step K, default) or ``"each"`` (at every observed
        step).
    method
        scipy least_squares method, ``"trf"`` (default) or ``"dogbox"``; both
        honour the model's parameter bounds.
    xtol, ftol, gtol
        least_squares tolerances (default 1e-10 each).
    max_nfev
        At most this many residual evaluations (path simulations) a fit
        (default 100).
    """

    reference: ClassVar[bool] = True  # the harness's E_ref: the best constant fit

    refit: str = "end"
    method: str = "trf"
    xtol: float = 1e-10
    ftol: float = 1e-10
    gtol: float = 1e-10
    max_nfev: int = 100

    def __post_init__(self) -> None:
        super().__post_init__()
        check_choice("refit", self.refit, REFITS)
        check_choice("method", self.method, METHODS)
        for name in ("xtol", "ftol", "gtol"):
            check_positive(name, getattr(self, name))
        if not (isinstance(self.max_nfev, int) and self.max_nfev >= 1):
            raise ValueError(
                f"max_nfev = {self.max_nfev!r} is not allowed; "
                "it must be an integer >= 1"
            )

    def estimate_solves(self, n_state: int, p: int, steps: int) -> int:
        """A few path simulations a fit: one fit of K steps, or one at each step.

        With ``refit = "each"`` the fit at step k simulates k steps (at most;
        only observed steps fit): K (K + 1) / 2 steps a round of evaluations.
        """
        path = steps if self.refit == "end" else steps * (steps + 1) // 2
        return min(TYPICAL_EVALUATIONS, self.max_nfev) * path

    def begin(self, model: ForwardModel, prior: Prior) -> None:
        """Begin a run: no observations yet; report the prior until the first fit."""
        self._mu, self._P = self.prior_xi(prior)
        self._xi, self._cov = self._mu.copy(), self._P.copy()
        self._obs: list[tuple[int, FloatArray, float]] = []  # (k, y, sigma)
        self._seen: list[ForwardModel] = []  # each one's model (masked if occluded)
        self._cache: tuple[bytes, int, list[FloatArray]] | None = None
        self._chol: list[FloatArray] | None = None
        spec = model.parameters
        lo = self.to_xi(np.asarray(spec.lower, dtype=float))
        hi = self.to_xi(np.asarray(spec.upper, dtype=float))
        self._bounds = (np.where(np.isfinite(lo), lo, -np.inf), hi)

    def _simulate(self, xi: FloatArray, n: int) -> list[FloatArray]:
        """States at steps 1..n with theta(xi) (the last path is cached)."""
        key = np.asarray(xi, dtype=float).tobytes()
        if self._cache is not None and self._cache[:2] == (key, n):
            return self._cache[2]
        model = self.model
        theta = self.to_theta(xi)
        u = np.asarray(model.reset(), dtype=float)
        states = []
        for k in range(1, n + 1):
            u = advance(model, theta, k, u)
            states.append(u)
        self._cache = (key, n, states)
        return states

    def _residuals(self, xi: FloatArray, n: int) -> FloatArray:
        states = self._simulate(xi, n)
        seen = self._seen
        if self._chol is not None:  # corrected model: whitened by chol(R + Sigma)
            return np.concatenate([
                solve_triangular(c, y - h.observe(states[k - 1]), lower=True)
                for (k, y, _), h, c in zip(self._obs, seen, self._chol, strict=True)
            ])  # fmt: skip
        return np.concatenate([
            (y - h.observe(states[k - 1])) / s
            for (k, y, s), h in zip(self._obs, seen, strict=True)
        ])  # fmt: skip

    def _jacobian(self, xi: FloatArray, n: int) -> FloatArray:
        seen = self._seen
        states = self._simulate(xi, n)
        theta, scale = self.to_theta(xi), self.dtheta_dxi(xi)
        if self._chol is not None:
            return np.vstack([
                -solve_triangular(
                    c, np.asarray(h.sensitivity(theta, k, states[k - 1])),  # type: ignore[attr-defined]
                    lower=True,
                ) * scale
                for (k, _, _), h, c in zip(self._obs, seen, self._chol, strict=True)
            ])  # fmt: skip
        rows = [
            -np.asarray(h.sensitivity(theta, k, states[k - 1])) * scale  # type: ignore[attr-defined]
            / np.reshape(s, (-1, 1))
            for (k, _, s), h in zip(self._obs, seen, strict=True)
        ]
        return np.vstack(rows)

    def _whitening(self, xi: FloatArray, n: int) -> list[FloatArray]:
        """Lower Cholesky factors of R + Sigma at each observed step's state at xi."""
        states = self._simulate(xi, n)
        out = []
        for (k, y, s), h in zip(self._obs, self._seen, strict=True):
            sigma = np.asarray(h.observation_cov(states[k - 1]), dtype=float)  # type: ignore[attr-defined]
            out.append(np.linalg.cholesky(s**2 * np.eye(y.size) + sigma))
        return out

    def _fit(self, k: int) -> FloatArray:
        """Fit xi to all observations so far, simulating steps 1..k."""
        lo, hi = self._bounds
        span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
        x0 = np.clip(self._xi, lo + 1e-9 * span, hi - 1e-9 * span)
        jac = self._jacobian if sensitivity_of(self.model) else "2-point"
        passes = 2 if self.correction == "approximation-error" else 1
        try:
            for _ in range(passes):
                if passes > 1:  # R + Sigma at the current iterate's states, kept
                    self._chol = self._whitening(x0, k)  # through the fit
                res = least_squares(
                    self._residuals,
                    x0,
                    jac=jac,
                    bounds=(lo, hi),
                    method=self.method,
                    xtol=self.xtol,
                    ftol=self.ftol,
                    gtol=self.gtol,
                    max_nfev=self.max_nfev,
                    args=(k,),
                )
                x0 = np.clip(res.x, lo + 1e-9 * span, hi - 1e-9 * span)
        except np.linalg.LinAlgError as exc:
            raise Diverged(f"least squares failed: {exc}", step=k) from exc
        xi = np.asarray(res.x, dtype=float)
        try:
            cov = np.linalg.inv(res.jac.T @ res.jac)
        except np.linalg.LinAlgError:
            cov = np.full((xi.size, xi.size), np.inf)
        self.check_estimate(xi, k)
        self._xi, self._cov = xi, cov
        return self._simulate(xi, k)[-1]

    def assimilate(self, k: int, observation: Observation | None) -> Analysis:
        """Record the observation; fit at step K ("end") or at each observation."""
        if observation is not None:
            y = np.asarray(observation.values, dtype=float)
            self._obs.append((k, y, np.sqrt(self.noise_var(observation))))
            model = self.run.model  # this observation's: masked by its own entries
            mask = self.visible
            self._seen.append(model if mask is None else MaskedModel(model, mask))  # type: ignore[arg-type]
        fit_now = bool(self._obs) and (
            k == self.model.n_steps if self.refit == "end" else observation is not None
        )
        state = self._fit(k) if fit_now else None
        return Analysis(self._xi, self._cov, state)

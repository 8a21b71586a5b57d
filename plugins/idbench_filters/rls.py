r"""Recursive least squares on the linearised observation map.

The estimator keeps one model state u, advanced at each step with the current
estimate (one forward solve a step). At an observation y of step k it
linearises h(xi) = observe(u_k(xi)) at the current xi:
J = dh/dxi (m, p) = J_theta diag(dtheta/dxi), from ``model.sensitivity`` (one
back-substitution per parameter) when the model has it, else forward finite
differences in xi (p extra solves). With forgetting factor lambda:

.. math::

    P^- = P / \lambda, \quad S = J P^- J^T + R, \quad K = P^- J^T S^{-1},
    \quad \xi \leftarrow \xi + K (y - h), \quad P = P^- - K S K^T.

Forgetting applies at observed steps only. With lambda = 1 and a linear model
this is the exact Gaussian posterior given the prior. The innovation
(y - h, S) is kept for the normalized innovation squared (NIS). The reported state is
the one the innovation was computed with (the estimate before the update).

With ``correction = "approximation-error"`` (:class:`idbench.Filter`) h is
the corrected model's (the coarse observation plus the calibrated mean
discrepancy, J its chain-ruled sensitivity (I + d mu/d z) J_c) and R the
full R + Sigma(h(u)) of :meth:`idbench.Filter.noise_cov`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from idbench import Analysis, Filter, ForwardModel, Observation, Prior
from idbench_filters.common import advance_linearised, check_positive


@dataclass
class Rls(Filter):
    """Recursive least squares with forgetting on xi.

    Attributes
    ----------
    forgetting
        Forgetting factor lambda in (0, 1]; 1 (default) forgets nothing.
    fd_step
        Relative finite-difference step in xi, used only when the model has no
        ``sensitivity``.
    """

    forgetting: float = 1.0
    fd_step: float = 1e-6

    def __post_init__(self) -> None:
        super().__post_init__()
        check_positive("forgetting", self.forgetting)
        if self.forgetting > 1:
            raise ValueError(
                f"forgetting = {self.forgetting!r} is not allowed; use 0 < lambda <= 1"
            )
        check_positive("fd_step", self.fd_step)

    def begin(self, model: ForwardModel, prior: Prior) -> None:
        """Begin a run from the prior; state = reset()."""
        self._xi, self._P = self.prior_xi(prior)
        self._u = np.asarray(model.reset(), dtype=float)

    def assimilate(self, k: int, observation: Observation | None) -> Analysis:
        """Advance the own state one step, then one RLS update if observed."""
        xi, P = self._xi, self._P
        u, linear = advance_linearised(
            self.model, xi, k, self._u, self.transformation, self.fd_step, observation
        )
        if linear is not None:
            J, e = linear
            Pm = P / self.forgetting
            S = J @ Pm @ J.T + self.noise_cov(observation, u)
            self.innovation = (e, S)  # the traces' NIS
            K = np.linalg.solve(S, J @ Pm).T  # (p, m); S symmetric
            xi = xi + K @ e
            P = Pm - K @ S @ K.T
            P = 0.5 * (P + P.T)
        self._xi, self._P, self._u = xi, P, u
        return Analysis(xi, P, u, finite=(P,))

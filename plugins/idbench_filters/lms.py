r"""Normalised least mean squares (stochastic gradient) on xi.

Like :mod:`idbench_filters.rls`, the estimator keeps one model state advanced
with the current estimate (one forward solve a step) and, at an observation,
linearises h(xi) = observe(u_k(xi)) with J = dh/dxi (m, p) from the model's
``sensitivity`` (else finite differences in xi). The update is the normalised
gradient step

.. math::

    \xi \leftarrow \xi + \mu \frac{J^T (y - h)}{\epsilon + \|J\|_F^2},

stable for 0 < mu < 2. LMS carries no covariance: its std is NaN. With
``correction = "approximation-error"`` (:class:`idbench.Filter`) h and J are
the corrected model's (the mean discrepancy added); having no noise model,
LMS uses no Sigma.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from idbench import Analysis, Filter, ForwardModel, Observation, Prior
from idbench_filters.common import advance_linearised, check_positive


@dataclass
class Lms(Filter):
    """Normalised LMS: xi += mu J^T e / (eps + |J|^2).

    Attributes
    ----------
    sigma_floor
        Kept for a uniform interface; LMS does not weight by the noise.
    mu
        Step size in (0, 2); 0.5 (default) halves a linear error per observation.
    eps
        Regularisation of the normalisation (units of |J|^2, m^2 per xi^2),
        default 1e-12.
    fd_step
        Relative finite-difference step in xi, used only when the model has no
        ``sensitivity``.
    """

    mu: float = 0.5
    eps: float = 1e-12
    fd_step: float = 1e-6

    def __post_init__(self) -> None:
        super().__post_init__()
        check_positive("mu", self.mu)
        if self.mu >= 2:
            raise ValueError(f"mu = {self.mu!r} is not allowed; use 0 < mu < 2")
        check_positive("eps", self.eps, allow_zero=True)
        check_positive("fd_step", self.fd_step)

    def begin(self, model: ForwardModel, prior: Prior) -> None:
        """Begin a run from the prior mean; state = reset()."""
        self._xi, _ = self.prior_xi(prior)
        self._u = np.asarray(model.reset(), dtype=float)

    def assimilate(self, k: int, observation: Observation | None) -> Analysis:
        """Advance the own state one step, then one gradient step if observed."""
        xi = self._xi
        u, linear = advance_linearised(
            self.model, xi, k, self._u, self.transformation, self.fd_step, observation
        )
        if linear is not None:
            J, e = linear
            xi = xi + self.mu * (J.T @ e) / (self.eps + float(np.sum(J * J)))
        self._xi, self._u = xi, u
        return Analysis(xi, None, u, finite=(u,))

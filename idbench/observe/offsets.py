r"""The approximation error a seen model adds to h(x): per frame, linear in ln theta.

A coarse model's prediction h_c differs from a finer model's h_f of the same
body by a discrepancy delta_k(theta) = h_f,k - h_c,k, frame by frame
(:mod:`idbench.calibrate.prior_mean` computes it on a run's own frames). An
:class:`Offsets` holds it as the seen model adds it,

.. math::

    \delta_k(\theta) \approx \mu_k + G_k (\ln\theta - \xi_0),
    \qquad y_k = h_{c,k}(\theta) + \delta_k(\theta) + e_k,
    \quad e_k \sim N(0, R + \Sigma_k):

the offset at the prior mean :math:`\theta_0 = e^{\xi_0}`, its slope in ln
theta (None: a constant offset) and the covariance of what that line leaves
unexplained (None: none).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from idbench.core.interfaces import FloatArray


@dataclass(frozen=True)
class Offsets:
    """An approximation error per frame (see the module doc).

    Attributes
    ----------
    mean
        mu_k (m,) for each step k = 1..K.
    slopes
        G_k (m, p), d delta_k / d ln theta at theta_0; None: constant offsets.
    xi0
        ln theta_0 (p,), where the slopes start (with ``slopes``).
    covs
        Sigma_k (m, m) for each step; None: no added covariance.
    """

    mean: list[FloatArray]
    slopes: list[FloatArray] | None = None
    xi0: FloatArray | None = None
    covs: list[FloatArray] | None = None

    def __post_init__(self) -> None:
        if (self.slopes is None) != (self.xi0 is None):
            raise ValueError("offsets: slopes and xi0 go together")

    @property
    def linear(self) -> bool:
        """Whether the offset depends on theta."""
        return self.slopes is not None

    def at(self, k: int, theta: FloatArray | None = None) -> FloatArray:
        """delta_k (m,) at theta (a linear offset needs it)."""
        mu = self.mean[k - 1]
        if self.slopes is None or self.xi0 is None:
            return mu
        if theta is None:
            raise ValueError("a linear offset needs theta")
        return mu + self.slopes[k - 1] @ (np.log(np.asarray(theta, float)) - self.xi0)

    def jacobian(self, k: int, theta: FloatArray) -> FloatArray:
        """D delta_k / d theta (m, p) (zeros for a constant offset)."""
        if self.slopes is None:
            return np.zeros((self.mean[k - 1].size, np.asarray(theta).size))
        return self.slopes[k - 1] / np.asarray(theta, dtype=float)[None, :]

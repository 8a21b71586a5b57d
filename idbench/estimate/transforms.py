r"""The parameter transforms an estimator works in: objects, not string branches.

An estimator (see :class:`idbench.Filter`) works on an unconstrained parameter
vector xi (p,). With :class:`LogTransform`, xi = log(theta) and the Gaussian
prior (mean E0, std s) in natural units becomes the log-normal with the same
mean and variance,

.. math::

    \mu_\xi = \ln E_0, \qquad \sigma_\xi^2 = \ln(1 + s^2 / E_0^2),

and estimates are reported as E = exp(mean xi) (the posterior median) with
E_std = E * std(xi). With :class:`IdentityTransform`, xi = theta.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from idbench.core.interfaces import FloatArray, Prior


@dataclass(frozen=True)
class IdentityTransform:
    """xi = theta (the base of the transforms: each method is the identity's).

    Attributes
    ----------
    name
        The value of an estimator's ``transform`` setting that selects it.
    """

    name: str = "identity"

    def to_xi(self, theta: FloatArray) -> FloatArray:
        """Natural parameters (p,) -> xi (p,)."""
        return np.array(theta, dtype=float)

    def to_theta(self, xi: FloatArray) -> FloatArray:
        """Xi (p,) -> natural parameters (p,)."""
        return np.array(xi, dtype=float)

    def dtheta_dxi(self, xi: FloatArray) -> FloatArray:
        """Diagonal of d theta / d xi, shape (p,)."""
        return np.ones_like(np.asarray(xi, dtype=float))

    def prior(self, mean: FloatArray, std: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Mean (p,) and covariance (p, p) of xi for a natural-unit prior."""
        return mean.copy(), np.diag(std**2)

    def std(self, theta: FloatArray, std_xi: FloatArray) -> FloatArray:
        """Natural-unit std (p,) from the std of xi."""
        return std_xi

    def prior_xi(self, prior: Prior, p: int) -> tuple[FloatArray, FloatArray]:
        """Prior mean (p,) and covariance (p, p) of xi.

        Raises
        ------
        ValueError
            If the prior has the wrong length, or (log transform) a
            non-positive mean.
        """
        mean = np.asarray(prior.mean, dtype=float)
        std = np.asarray(prior.std, dtype=float)
        if mean.shape != (p,):
            raise ValueError(
                f"prior has {mean.size} entries but the model has p = {p}"
            )
        return self.prior(mean, std)


@dataclass(frozen=True)
class LogTransform(IdentityTransform):
    """xi = ln theta: every value of xi is a positive parameter."""

    name: str = "log"

    def to_xi(self, theta: FloatArray) -> FloatArray:
        """Natural parameters (p,) -> xi (p,)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.log(np.asarray(theta, dtype=float))

    def to_theta(self, xi: FloatArray) -> FloatArray:
        """Xi (p,) -> natural parameters (p,)."""
        with np.errstate(over="ignore"):
            return np.exp(np.asarray(xi, dtype=float))

    def dtheta_dxi(self, xi: FloatArray) -> FloatArray:
        """Diagonal of d theta / d xi, shape (p,): theta."""
        return self.to_theta(xi)

    def prior(self, mean: FloatArray, std: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The log-normal with the prior's mean and variance (see module doc)."""
        if np.any(mean <= 0):
            raise ValueError(
                f"the log transform needs a positive prior mean, got {mean}"
            )
        return np.log(mean), np.diag(np.log1p(std**2 / mean**2))

    def std(self, theta: FloatArray, std_xi: FloatArray) -> FloatArray:
        """Natural-unit std (p,): theta * std(xi)."""
        return theta * std_xi


TRANSFORMS: dict[str, IdentityTransform] = {
    t.name: t for t in (LogTransform(), IdentityTransform())
}
"""Transform by its setting value (``"log"``, ``"identity"``)."""

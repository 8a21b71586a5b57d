r"""A low-rank Laplace posterior from a randomized eigensolver.

At a MAP point of J(xi) = 1/2 sum_k |y_k - h_k(xi)|^2_{R^-1} + 1/2 |xi - mu|^2_{Q},
with the prior Sigma = F F^T, write xi = mu + F z. The Gauss-Newton Hessian
in z is I + H_d, H_d = F^T (sum_k J_k^T R_k^-1 J_k) F the *prior-preconditioned
data-misfit Hessian*. Its eigenvalues say how much each direction is
informed by the data beyond the prior (lambda >> 1: the data rule; << 1: the
prior does), so a few eigenpairs H_d ~ V diag(lambda) V^T carry the update
(Bui-Thanh, Ghattas, Martin, Stadler 2013; hIPPYlib):

.. math::

    \Gamma_{post} = F (I + H_d)^{-1} F^T
    \approx F \left(I - V \operatorname{diag}\frac{\lambda}{1 + \lambda}
    V^T\right) F^T,

exact when the rank reaches that of H_d. The eigenpairs come from
:func:`randomized_eigh` (Halko, Martinsson, Tropp 2011, the two-pass
algorithm on a matvec): r + oversampling products with H_d and a QR.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

OVERSAMPLING = 10
"""Extra random directions of :func:`randomized_eigh`."""


def randomized_eigh(
    matvec: Callable[[FloatArray], FloatArray],
    p: int,
    rank: int,
    rng: np.random.Generator,
    oversampling: int = OVERSAMPLING,
) -> tuple[FloatArray, FloatArray]:
    """The ``rank`` largest eigenpairs of a symmetric p x p operator.

    Parameters
    ----------
    matvec
        X (p, q) -> H X (p, q), H symmetric positive semi-definite.
    p
        Its size.
    rank
        Eigenpairs wanted (at most p).
    rng
        For the random test matrix.
    oversampling
        Extra directions (accuracy; all of them when rank + oversampling >= p).

    Returns
    -------
    tuple
        Eigenvalues (r,), descending, and eigenvectors (p, r), orthonormal.
    """
    rank = min(int(rank), p)
    k = min(rank + int(oversampling), p)
    omega = rng.standard_normal((p, k))
    Q, _ = np.linalg.qr(matvec(omega))
    T = Q.T @ matvec(Q)
    lam, S = np.linalg.eigh(0.5 * (T + T.T))
    order = np.argsort(lam)[::-1][:rank]
    return np.maximum(lam[order], 0.0), Q @ S[:, order]


@dataclass(frozen=True)
class LaplacePosterior:
    """N(xi_map, F (I - V D V^T) F^T), D = diag(lambda / (1 + lambda)).

    Attributes
    ----------
    mean
        (p,) the MAP point.
    factor
        (p, p) the prior's F.
    values, vectors
        (r,) and (p, r): the eigenpairs of H_d kept.
    """

    mean: FloatArray
    factor: FloatArray
    values: FloatArray
    vectors: FloatArray

    @property
    def cov(self) -> FloatArray:
        """The posterior covariance (p, p)."""
        V = self.vectors
        inner = np.eye(len(self.mean)) - (V * (self.values / (1 + self.values))) @ V.T
        return np.asarray(self.factor @ inner @ self.factor.T)

    @property
    def std(self) -> FloatArray:
        """The marginal std (p,) (the diagonal of :attr:`cov`, without forming it)."""
        F = self.factor
        G = F @ self.vectors
        d = np.einsum("ij,ij->i", F, F) - (G * G) @ (self.values / (1 + self.values))
        return np.asarray(np.sqrt(np.maximum(d, 0.0)))


def laplace(
    mean: FloatArray,
    factor: FloatArray,
    matvec: Callable[[FloatArray], FloatArray],
    rank: int,
    rng: np.random.Generator,
) -> LaplacePosterior:
    """The low-rank Laplace posterior at ``mean`` from H_d's ``matvec`` (z space)."""
    values, vectors = randomized_eigh(matvec, len(mean), rank, rng)
    return LaplacePosterior(np.asarray(mean, float), np.asarray(factor, float),
                            values, vectors)  # fmt: skip

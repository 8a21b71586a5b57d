r"""A smoothness prior on a parameter field: Gaussian in log-value, Matérn-type.

The cells of a :class:`~idbench.core.field.ParameterField` carry x = ln theta.
The prior is the finite-volume discretisation of the SPDE of Lindgren, Rue and
Lindström (2011) with alpha = 2,

.. math::

    (\kappa^2 - \Delta)\, x = \mathcal{W}, \qquad
    A = \kappa^2 M + L, \qquad Q_0 = A M^{-1} A,

with M = diag(cell volumes) and L the graph Laplacian of the cells' adjacency
weighted by shared area over centroid distance (L_ij = -a_ij / |c_i - c_j|,
L_ii = -sum_j L_ij): a two-point flux, so Q_0 approximates the continuum
operator on any partition. Its covariance is Matérn with smoothness
nu = alpha - d/2 (1/2 in 3-D: exponential), and

.. math::

    \kappa = \sqrt{8 \nu} / \rho,

rho the *correlation length*: the distance at which two cells' log-values
are correlated about 0.14 (exp(-2) in 3-D; (1 + sqrt 12) exp(-sqrt 12) in
1-D). In millimetres: with rho = 20 mm, points 5 mm apart are correlated
0.61, 10 mm 0.37, 20 mm 0.14, 40 mm 0.02 (3-D). The SPDE's marginal variance
grows near the boundary and with the discretisation; the prior here is
scaled cell by cell so that every marginal std is exactly ``std`` (the
second setting), keeping the correlation of Q_0:

.. math::

    \Sigma = D_\sigma\, C\, D_\sigma,\quad C = D_s^{-1} Q_0^{-1} D_s^{-1},
    \quad s_i = (Q_0^{-1})_{ii}^{1/2},

held as Sigma = F F^T with F = D_{sigma/s} A^{-1} M^{1/2} (no Cholesky), and
Q = Sigma^{-1} = F^{-T} F^{-1}. Dense: fields of up to :data:`DENSE_LIMIT`
cells.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from idbench.core.field import FloatArray, ParameterField

DENSE_LIMIT = 5000
"""Cells above which the dense prior refuses (memory ~ 8 p^2 bytes, p^3 work)."""


def smoothness(dim: int) -> float:
    """Matérn smoothness nu = 2 - d/2 of the alpha = 2 SPDE in ``dim`` dimensions."""
    return 2.0 - dim / 2.0


def kappa(length: float, dim: int) -> float:
    """The SPDE's kappa = sqrt(8 nu) / rho for correlation length ``length``."""
    return math.sqrt(8.0 * smoothness(dim)) / float(length)


def laplacian(field: ParameterField) -> FloatArray:
    """L (p, p): the two-point-flux graph Laplacian of the cells, dense."""
    p = field.p
    L = np.zeros((p, p))
    if len(field.edges):
        i, j = field.edges[:, 0], field.edges[:, 1]
        dist = np.linalg.norm(field.centroids[i] - field.centroids[j], axis=1)
        w = field.areas / np.maximum(dist, 1e-300)
        np.add.at(L, (i, j), -w)
        np.add.at(L, (j, i), -w)
        np.add.at(L, (i, i), w)
        np.add.at(L, (j, j), w)
    return L


def spde_operator(field: ParameterField, length: float | None = None) -> FloatArray:
    """A = kappa^2 M + L (p, p), with the field's (or the given) length."""
    rho = field.length if length is None else float(length)
    k = kappa(rho, field.dim)
    return k * k * np.diag(field.volumes) + laplacian(field)


@dataclass(frozen=True, eq=False)
class FieldPrior:
    """N(mean, Sigma) on the log-values of a field's cells (see the module).

    Attributes
    ----------
    mean
        (p,) prior mean of x = ln theta.
    factor
        (p, p) F with Sigma = F F^T.
    correlation
        (p, p) the correlation matrix C.
    std
        (p,) the marginal std of each cell.
    """

    mean: FloatArray
    factor: FloatArray
    correlation: FloatArray
    std: FloatArray

    @classmethod
    def of(
        cls,
        field: ParameterField,
        mean: FloatArray,
        std: float | FloatArray,
        length: float | None = None,
    ) -> FieldPrior:
        """The prior of ``field`` with marginal ``std`` (scalar or (p,)).

        ``length`` overrides the field's correlation length (m).

        Raises
        ------
        ValueError
            Above :data:`DENSE_LIMIT` cells, or a std that is not > 0.
        """
        p = field.p
        if p > DENSE_LIMIT:
            raise ValueError(
                f"a field of {p} cells is over the dense prior's limit of "
                f"{DENSE_LIMIT}; use fewer cells"
            )
        sigma = np.broadcast_to(np.asarray(std, dtype=float), (p,)).copy()
        if not np.all(np.isfinite(sigma) & (sigma > 0)):
            raise ValueError(f"prior std must be finite and > 0, got {std!r}")
        A = spde_operator(field, length)
        G = np.linalg.solve(A, np.diag(np.sqrt(field.volumes)))  # A^-1 M^1/2
        s = np.sqrt(np.einsum("ij,ij->i", G, G))
        factor = (sigma / s)[:, None] * G
        unit = G / s[:, None]
        correlation = unit @ unit.T
        mu = np.broadcast_to(np.asarray(mean, dtype=float), (p,)).copy()
        return cls(mu, factor, correlation, sigma)

    @property
    def p(self) -> int:
        """Number of cells."""
        return len(self.mean)

    @property
    def cov(self) -> FloatArray:
        """Sigma (p, p) = F F^T."""
        return np.asarray(self.factor @ self.factor.T)

    @property
    def precision(self) -> FloatArray:
        """Q (p, p) = Sigma^-1 = F^-T F^-1."""
        Finv = np.linalg.inv(self.factor)
        return np.asarray(Finv.T @ Finv)

    def whiten(self, x: FloatArray) -> FloatArray:
        """The prior-whitened z = F^-1 (x - mean) of x (p,) or (p, q)."""
        d = np.asarray(x, dtype=float)
        d = d - (self.mean if d.ndim == 1 else self.mean[:, None])
        return np.asarray(np.linalg.solve(self.factor, d))

    def energy(self, x: FloatArray) -> float:
        """1/2 (x - mean)^T Q (x - mean)."""
        z = self.whiten(x)
        return 0.5 * float(z @ z)

    def gradient(self, x: FloatArray) -> FloatArray:
        """Q (x - mean), (p,)."""
        z = self.whiten(x)
        return np.asarray(np.linalg.solve(self.factor.T, z))

    def sample(self, rng: np.random.Generator, n: int) -> FloatArray:
        """``n`` draws (n, p) of N(mean, Sigma) from ``rng``."""
        z = rng.standard_normal((n, self.p))
        return np.asarray(self.mean[None, :] + z @ self.factor.T)

r"""Localized ensemble filters for parameter fields: the EnKF and the ETKF.

With tens or hundreds of cells and an ensemble of a few tens, the sample
covariance between a cell and an observation far from it is noise, and an
update through it is spurious. Localization cuts it by distance between the
cell's centroid (:class:`idbench.ParameterField`) and the observed point
(``observation_points``, :class:`idbench.ObservationPointsModel`) with the
Gaspari-Cohn taper rho (:func:`gaspari_cohn`: 1 at distance 0, 0 beyond
``localization``, compactly supported fifth-order, positive definite).
A value with no position (a resultant force: NaN) is not localized, nor are
the state's rows (the displacements, which each member's next step solves
again from its own parameters).

- :class:`LocalizedEnkf`: covariance localization of the gain (Houtekamer
  and Mitchell 2001). With anomalies A (N, n), Y (N, m),

  .. math::

      K = (\rho_{xy} \circ A^T Y)(\rho_{yy} \circ Y^T Y + (N-1) R)^{-1},
      \quad x_i \leftarrow x_i + K (y + d_i - h_i),

  rho_xy (n, m) the taper of each parameter row against each observation
  (1 on state rows) and rho_yy (m, m) between observations.
- :class:`LocalizedEtkf`: a local analysis per cell (the LETKF of Hunt,
  Kostelich and Szunyogh 2007) with observation-error localization:
  cell j's ensemble-space transform uses R_j^-1 = diag(rho_j) R^-1, the
  state rows the global (untapered) one. The cells' N x N eigenproblems are
  solved as one stacked call.

The initial members are drawn from the field's smoothness prior (``smooth``,
the prior :mod:`idbench_filters.map_laplace` uses). ``localization = None``
(and ``smooth = False``) turns it off: both then take the taper 1
everywhere and equal the plain :class:`~idbench_filters.enkf.Enkf` and
:class:`~idbench_filters.etkf.Etkf` to round-off (same draws). A model
without a field or observation points cannot be localized (skipped, saying
so) unless it is off.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from idbench import (
    Analysis,
    FieldPrior,
    ForwardModel,
    Observation,
    Prior,
    Skipped,
    noise_matrix,
    observation_points_of,
    parameter_field_of,
)
from idbench_filters.common import FloatArray, check_positive
from idbench_filters.enkf import Enkf
from idbench_filters.ensemble import draw_prior
from idbench_filters.etkf import Etkf


def gaspari_cohn(distance: FloatArray, support: float) -> FloatArray:
    """Gaspari and Cohn's (1999, eq. 4.10) taper, zero beyond ``support`` = 2c."""
    r = np.abs(np.asarray(distance, dtype=float)) / (0.5 * support)
    out = np.zeros_like(r)
    near = r <= 1
    far = (r > 1) & (r < 2)
    x = r[near]
    out[near] = -0.25 * x**5 + 0.5 * x**4 + 0.625 * x**3 - 5 / 3 * x**2 + 1
    x = r[far]
    out[far] = (x**5 / 12 - 0.5 * x**4 + 0.625 * x**3 + 5 / 3 * x**2 - 5 * x + 4
                - 2 / (3 * x))  # fmt: skip
    return out


def taper(
    cells: FloatArray, points: FloatArray, support: float | None
) -> FloatArray:
    """The taper rho (p, m) of cell centroids (p, d) and points (m, d); NaN: 1."""
    p, m = len(cells), len(points)
    if support is None:
        return np.ones((p, m))
    out = np.ones((p, m))
    local = np.all(np.isfinite(points), axis=1)
    d = np.linalg.norm(cells[:, None, :] - points[None, local, :], axis=2)
    out[:, local] = gaspari_cohn(d, support)
    return out


def _taper_yy(points: FloatArray, support: float | None) -> FloatArray:
    """The taper rho (m, m) between observation points; 1 where one has none."""
    m = len(points)
    if support is None:
        return np.ones((m, m))
    local = np.all(np.isfinite(points), axis=1)
    out = np.ones((m, m))
    d = np.linalg.norm(points[local][:, None] - points[local][None], axis=2)
    out[np.ix_(local, local)] = gaspari_cohn(d, support)
    return out


@dataclass
class _Localized:
    """What both localized filters share: the settings and the step's tapers."""

    localization: float | None = None
    smooth: bool = True

    def _check_localization(self) -> None:
        if self.localization is not None:
            check_positive("localization", self.localization)
        if not isinstance(self.smooth, bool):
            raise ValueError(f"smooth = {self.smooth!r} is not allowed; use true/false")

    def _begin_localized(self, model: ForwardModel, prior: Prior) -> None:
        field = parameter_field_of(model)
        self._cells = None if field is None else field.centroids
        if field is not None and self.smooth:  # members from the smoothness prior
            mu, cov = self.prior_xi(prior)  # type: ignore[attr-defined]
            std = field.std or np.sqrt(np.diag(cov))
            smooth = FieldPrior.of(field, mu, std)
            X = self._X  # type: ignore[has-type]
            exact = self.init == "exact"  # type: ignore[attr-defined]
            X[:, self._nu :] = draw_prior(self._rng, mu, smooth.cov, len(X), exact)  # type: ignore[has-type]
        if self.localization is None:
            return
        if field is None or observation_points_of(model) is None:
            raise Skipped(
                "localization needs a model with a parameter_field and "
                "observation_points; set localization = none for this model"
            )
        if getattr(self, "correction", "none") == "approximation-error":
            raise Skipped("localization has no approximation-error correction")

    def _points(self, k: int, m: int, model: ForwardModel) -> FloatArray:
        points = observation_points_of(model)
        if self.localization is None or points is None:
            return np.full((m, 1), np.nan)
        return np.asarray(points(k), dtype=float)

    def __post_init__(self) -> None:
        super().__post_init__()  # type: ignore[misc]
        self._check_localization()

    def begin(self, model: ForwardModel, prior: Prior) -> None:
        """The plain filter's start, and the cells to localize."""
        super().begin(model, prior)  # type: ignore[misc]
        self._begin_localized(model, prior)

    def assimilate(self, k: int, observation: Observation | None) -> Analysis:
        """The plain filter's step, with the tapers of step k's observation points."""
        if observation is not None:
            m = np.size(observation.values)
            self._step_points = self._points(k, m, self.model)  # type: ignore[attr-defined]
        return super().assimilate(k, observation)  # type: ignore[misc, no-any-return]


@dataclass
class LocalizedEnkf(_Localized, Enkf):
    """EnKF with Gaspari-Cohn covariance localization of the gain.

    Attributes
    ----------
    localization
        Distance (m) beyond which an observation does not update a cell (the
        taper's support); None: off (the plain EnKF).
    smooth
        Draw the initial parameters from the field's smoothness prior
        (:mod:`idbench.estimate.prior`; its std, else the comparison's);
        False: the comparison's independent prior, as the plain EnKF.
    """

    by_default: ClassVar[bool] = False  # for fields: name it

    def analysis(
        self, X: FloatArray, HX: FloatArray, y: FloatArray, r: float
    ) -> FloatArray:
        """Perturbed-observation update with the tapered gain."""
        n_members, m = HX.shape
        A = X - X.mean(axis=0)
        Y = HX - HX.mean(axis=0)
        points = self._step_points
        rho = np.ones((X.shape[1], m))
        if self._cells is not None and self.localization is not None:
            rho[self._nu :] = taper(self._cells, points, self.localization)
        C = _taper_yy(points, self.localization) * (Y.T @ Y)
        C += (n_members - 1) * noise_matrix(r, m)
        innov = self._perturbed_innovations(HX, y, r)
        return X + innov @ np.linalg.solve(C, (rho * (A.T @ Y)).T)


@dataclass
class LocalizedEtkf(_Localized, Etkf):
    """ETKF with a local analysis per cell (observation-error localization).

    Attributes
    ----------
    localization
        Distance (m) beyond which an observation does not update a cell (the
        taper's support); None: off (the plain ETKF).
    smooth
        Draw the initial parameters from the field's smoothness prior; False:
        the comparison's independent prior, as the plain ETKF.
    """

    by_default: ClassVar[bool] = False  # for fields: name it

    def analysis(
        self, X: FloatArray, HX: FloatArray, y: FloatArray, r: float
    ) -> FloatArray:
        """The global transform for the state rows, a local one per cell."""
        out = super().analysis(X, HX, y, r)
        if self._cells is None or self.localization is None:
            return out
        n_members, nu = X.shape[0], self._nu
        xbar = X.mean(axis=0)
        A = X[:, nu:] - xbar[nu:]
        hbar = HX.mean(axis=0)
        Y = HX - hbar
        rinv = np.broadcast_to(1.0 / np.asarray(r, dtype=float), hbar.shape)
        rho = taper(self._cells, self._step_points, self.localization) * rinv  # (p, m)
        M = (Y[None, :, :] * rho[:, None, :]) @ Y.T  # (p, N, N)
        M += (n_members - 1) * np.eye(n_members)
        d, V = np.linalg.eigh(M)  # (p, N), (p, N, N)
        b = np.einsum("pm,m,im->pi", rho, y - hbar, Y)  # (p, N)
        w = np.einsum("pij,pj,pkj,pk->pi", V, 1.0 / d, V, b)
        T = np.sqrt(n_members - 1) * np.einsum("pij,pj,pkj->pik", V, d**-0.5, V)
        W = w[:, None, :] + T  # (p, N members out, N in)
        out[:, nu:] = xbar[nu:] + np.einsum("pik,kp->ip", W, A)
        return out

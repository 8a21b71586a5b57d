r"""Stochastic ensemble Kalman filter (perturbed observations).

Evensen (1994), Burgers, van Leeuwen & Evensen (1998), on the joint state
x = [u; xi] (see :mod:`idbench_filters.ensemble` for the ensemble, the
forecast and the inflation). With the forecast members x_i (rows of X,
N of them), their predicted observations h_i = observe(u_i), anomalies
A = X - xbar and Y = HX - hbar, and R = r I:

.. math::

    K = A^T Y \, (Y^T Y + (N - 1) R)^{-1}, \qquad
    x_i \leftarrow x_i + K (y + d_i - h_i),

with perturbations d_i ~ N(0, R) drawn from the filter's Generator and
centred (sum_i d_i = 0), so the analysis mean is the Kalman update of the
forecast mean. For a linear-Gaussian model the ensemble mean and covariance
converge to the Kalman filter's as N grows (Monte-Carlo error ~ N^-1/2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from idbench import noise_matrix
from idbench_filters.common import FloatArray
from idbench_filters.ensemble import EnsembleFilter


@dataclass
class Enkf(EnsembleFilter):
    """Stochastic EnKF with perturbed, centred observations on [state; xi].

    Its settings are the ensemble base's (:class:`~.ensemble.EnsembleFilter`);
    ``seed`` also draws the observation perturbations of every analysis.
    """

    def analysis(
        self, X: FloatArray, HX: FloatArray, y: FloatArray, r: float
    ) -> FloatArray:
        """Perturbed-observation update of the forecast ensemble X (N, n)."""
        n_members, m = HX.shape
        A = X - X.mean(axis=0)
        Y = HX - HX.mean(axis=0)
        C = Y.T @ Y + (n_members - 1) * noise_matrix(r, m)
        innov = self._perturbed_innovations(HX, y, r)
        return X + (innov @ np.linalg.solve(C, Y.T)) @ A

    def _perturbed_innovations(
        self, HX: FloatArray, y: FloatArray, r: float
    ) -> FloatArray:
        """The innovations y + d_i - h_i (N, m), d_i ~ N(0, R) drawn and centred."""
        n_members, m = HX.shape
        d = self._rng.standard_normal((n_members, m)) * np.sqrt(r)
        d -= d.mean(axis=0)
        return y[None, :] + d - HX

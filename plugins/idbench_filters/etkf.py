r"""Ensemble transform Kalman filter (deterministic square root).

Bishop, Etherton & Majumdar (2001), in the symmetric form of Hunt, Kostelich
& Szunyogh (2007), on the joint state x = [u; xi] (see
:mod:`idbench_filters.ensemble` for the ensemble, the forecast and the
inflation). With forecast anomalies A = X - xbar (N, n), Y = HX - hbar
(N, m), the innovation dy = y - hbar and R = r I, in ensemble space:

.. math::

    V \operatorname{diag}(d) V^T = (N - 1) I_N + Y R^{-1} Y^T, \quad
    w = dy^T R^{-1} Y^T V \operatorname{diag}(d^{-1}) V^T, \quad
    T = \sqrt{N - 1} \, V \operatorname{diag}(d^{-1/2}) V^T,

    X \leftarrow xbar + w A + T A.

The symmetric square root T keeps the anomalies centred. No random numbers
are used after the initial draw. For a linear-Gaussian model with an initial
ensemble of exact prior moments (``init = "exact"``, N >= p + 1) the mean and
covariance equal the Kalman filter's to round-off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from idbench_filters.common import FloatArray
from idbench_filters.ensemble import EnsembleFilter


@dataclass
class Etkf(EnsembleFilter):
    """Deterministic square-root ensemble filter (ETKF) on [state; xi].

    Settings: :class:`~.ensemble.EnsembleFilter`'s; ``seed`` seeds the initial
    draw only (the analysis is deterministic).
    """

    def analysis(
        self, X: FloatArray, HX: FloatArray, y: FloatArray, r: float
    ) -> FloatArray:
        """Symmetric square-root update of the forecast ensemble X (N, n)."""
        n_members = X.shape[0]
        xbar = X.mean(axis=0)
        A = X - xbar
        hbar = HX.mean(axis=0)
        Y = HX - hbar
        if np.ndim(r) == 0:
            d, V = np.linalg.eigh((n_members - 1) * np.eye(n_members) + Y @ Y.T / r)
            w = ((y - hbar) @ Y.T / r) @ (V / d) @ V.T
        else:  # one variance per value
            d, V = np.linalg.eigh((n_members - 1) * np.eye(n_members) + (Y / r) @ Y.T)
            w = (((y - hbar) / r) @ Y.T) @ (V / d) @ V.T
        T = np.sqrt(n_members - 1) * (V / np.sqrt(d)) @ V.T
        return xbar + (w[None, :] + T) @ A

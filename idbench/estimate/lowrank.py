"""A covariance held as a diagonal plus a low-rank part: S = diag(d) + F F^T.

Filters with few sigma points and many observed values (a point cloud of
thousands of points) can report their innovation covariance this way
instead of an (m, m) matrix: :func:`idbench.score.metrics.nis` then solves with
it by the Woodbury identity in O(m r^2), not O(m^3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class LowRankCovariance:
    """S = diag(diag) + factor factor^T.

    Attributes
    ----------
    diag
        The diagonal part d, shape (m,), positive.
    factor
        F, shape (m, r).
    """

    diag: FloatArray
    factor: FloatArray

    @property
    def shape(self) -> tuple[int, int]:
        """(m, m)."""
        m = int(np.size(self.diag))
        return m, m

    def solve(self, v: FloatArray) -> FloatArray:
        r"""S^-1 v (m,), by Woodbury: D^-1 v - D^-1 F (I + F^T D^-1 F)^-1 F^T D^-1 v."""
        d = np.asarray(self.diag, dtype=float)
        F = np.asarray(self.factor, dtype=float)
        dv = v / d
        dF = F / d[:, None]
        small = np.eye(F.shape[1]) + F.T @ dF
        return np.asarray(dv - dF @ np.linalg.solve(small, F.T @ dv))

    def dense(self) -> FloatArray:
        """S as an (m, m) array."""
        F = np.asarray(self.factor, dtype=float)
        return np.diag(np.asarray(self.diag, dtype=float)) + F @ F.T

r"""Proper orthogonal decomposition: a reduced basis from displacement snapshots.

The snapshots u_1..u_N (free displacements of the fine model along the
design's paths) are the columns of U (n x N); its thin SVD U = Phi Sigma
W^T gives the POD modes Phi, orthonormal and ordered by the energy
sigma_i^2 they carry. The first r modes are the best rank-r basis for the
snapshots in the least-squares sense:

.. math::

    \sum_j \| u_j - \Phi_r \Phi_r^T u_j \|^2 = \sum_{i > r} \sigma_i^2 .

:func:`modes_for` picks r from a tolerance on that share of the energy left
out, :math:`\sum_{i>r} \sigma_i^2 / \sum_i \sigma_i^2`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def pod(snapshots: FloatArray) -> tuple[FloatArray, FloatArray]:
    """POD modes (n, N') and singular values (N',) of snapshots (N, n).

    Modes whose singular value is below 1e-12 of the largest (round-off)
    are dropped, so N' <= min(N, n).

    Raises
    ------
    ValueError
        No snapshot, or snapshots that are all zero or not finite.
    """
    U = np.asarray(snapshots, dtype=np.float64)
    if U.ndim != 2 or not len(U):
        raise ValueError("POD needs at least one snapshot (N, n)")
    if not np.all(np.isfinite(U)):
        raise ValueError("POD snapshots must be finite")
    _, s, wt = np.linalg.svd(U, full_matrices=False)
    if not s.size or s[0] <= 0:
        raise ValueError("POD snapshots are all zero")
    keep = s > 1e-12 * s[0]
    return np.ascontiguousarray(wt[keep].T), s[keep]


def modes_for(singular: FloatArray, tolerance: float) -> int:
    """The fewest modes whose left-out energy share is <= ``tolerance``."""
    if not 0 < tolerance < 1:
        raise ValueError(f"POD tolerance {tolerance!r}: need 0 < tol < 1")
    energy = np.asarray(singular, dtype=float) ** 2
    left = 1.0 - np.cumsum(energy) / energy.sum()  # left out with i + 1 modes
    return int(np.argmax(left <= tolerance)) + 1 if np.any(left <= tolerance) else len(
        energy
    )


def projection_error(basis: FloatArray, snapshots: FloatArray) -> float:
    """Largest relative projection error max_j |u_j - V V^T u_j| / max_j |u_j|."""
    U = np.asarray(snapshots, dtype=float)
    V = np.asarray(basis, dtype=float)
    R = U - (U @ V) @ V.T
    scale = float(np.max(np.linalg.norm(U, axis=1))) or 1.0
    return float(np.max(np.linalg.norm(R, axis=1)) / scale)

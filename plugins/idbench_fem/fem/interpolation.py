"""Marker and grid points: placement on the beam, location in the mesh, P1 probes.

Points are located once (vectorised barycentric search over the nearest
elements of a k-d tree of centroids, with a brute-force fallback) and turned
into a sparse interpolation matrix acting on the free displacements.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.spatial import cKDTree

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_CANDIDATES = 16
_TOL = 1e-9


def marker_points(m: int, lower: FloatArray, upper: FloatArray) -> FloatArray:
    """Place ``m`` markers on the beam's end face and top edges, shape (m, 3).

    Order: the two top end-face corners (L, 0, H), (L, W, H); then the bottom
    ones (L, 0, 0), (L, W, 0); then points along the two top edges (z = H,
    y = 0 and y = W), alternating edges, evenly spaced from the tip towards
    the clamp (both ends excluded).
    """
    if m < 1:
        raise ValueError(f"markers = {m}: need at least one marker")
    (x0, y0, z0), (x1, y1, z1) = lower, upper
    corners = [(x1, y0, z1), (x1, y1, z1), (x1, y0, z0), (x1, y1, z0)]
    pts = corners[:m]
    rest = m - len(pts)
    if rest > 0:
        per_edge = math.ceil(rest / 2)
        for j in range(rest):
            i = j // 2 + 1
            x = x1 - (x1 - x0) * i / (per_edge + 1)
            pts.append((x, y0 if j % 2 == 0 else y1, z1))
    return np.asarray(pts, dtype=float)


def grid_points(
    counts: tuple[int, int, int], lower: FloatArray, upper: FloatArray
) -> FloatArray:
    """Regular grid strictly inside the box: cell centres, shape (nx*ny*nz, 3).

    ``counts`` = (nx, ny, nz) points along x, y, z; x varies slowest.
    """
    if len(counts) != 3 or any(int(c) < 1 for c in counts):
        raise ValueError(f"grid {counts!r}: need three point counts >= 1")
    axes = [
        lo + (np.arange(n) + 0.5) * (hi - lo) / n
        for lo, hi, n in zip(lower, upper, counts, strict=True)
    ]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def barycentric(points: FloatArray, x: FloatArray) -> FloatArray:
    """Barycentric coordinates of ``points`` (..., 3) in tets ``x`` (..., 4, 3)."""
    jac = np.stack([x[..., 1, :] - x[..., 0, :], x[..., 2, :] - x[..., 0, :],
                    x[..., 3, :] - x[..., 0, :]], axis=-1)  # fmt: skip
    lam = np.linalg.solve(jac, (points - x[..., 0, :])[..., None])[..., 0]
    return np.concatenate([1.0 - lam.sum(axis=-1, keepdims=True), lam], axis=-1)


class OutsideMesh(ValueError):
    """A point lies outside the mesh; ``index`` is its index in the points given."""

    def __init__(self, message: str, index: int) -> None:
        super().__init__(message)
        self.index = index


def locate(
    points: FloatArray, nodes: FloatArray, tets: NDArray[np.int64]
) -> tuple[NDArray[np.int64], FloatArray]:
    """Find the tet containing each point and its barycentric coordinates.

    Returns
    -------
    elements
        Tet index per point, shape (P,).
    bary
        Barycentric coordinates, shape (P, 4).

    Raises
    ------
    OutsideMesh
        If a point lies outside the mesh (a ValueError).
    """
    points = np.atleast_2d(np.asarray(points, dtype=float))
    x = nodes[tets]
    scale = float(np.max(np.ptp(nodes, axis=0)))
    k = min(_CANDIDATES, len(tets))
    _, cand = cKDTree(x.mean(axis=1)).query(points, k=k)
    cand = np.asarray(cand).reshape(len(points), k)
    bary = barycentric(points[:, None, :], x[cand])  # (P, k, 4)
    worst = bary.min(axis=2)
    best = worst.argmax(axis=1)
    rows = np.arange(len(points))
    elements = cand[rows, best]
    out = bary[rows, best]
    miss = np.flatnonzero(worst[rows, best] < -_TOL)
    for i in miss:  # fallback: all tets (rare; big elements far from the point)
        b = barycentric(np.broadcast_to(points[i], (len(tets), 3)), x)
        j = int(b.min(axis=1).argmax())
        if b[j].min() < -_TOL * max(1.0, scale):
            raise OutsideMesh(
                f"point {points[i].tolist()} lies outside the mesh", int(i)
            )
        elements[i], out[i] = j, b[j]
    return elements, out


def interpolation_matrix(
    points: FloatArray,
    nodes: FloatArray,
    tets: NDArray[np.int64],
    full_to_free: NDArray[np.int64],
) -> sp.csr_matrix:
    """Sparse P1 interpolation (3P, n_free): point displacements from the state.

    Row ``3 i + c`` gives component c at point i; clamped nodes contribute zero.
    """
    elements, bary = locate(points, nodes, tets)
    return weights_matrix(tets[elements], bary, full_to_free)


def weights_matrix(
    nodes: IntArray, weights: FloatArray, full_to_free: IntArray
) -> sp.csr_matrix:
    """(3P, n_free) interpolation from node indices (P, k) and weights (P, k)."""
    n_pts, k = nodes.shape
    rows = np.broadcast_to(
        3 * np.arange(n_pts)[:, None, None] + np.arange(3), (n_pts, k, 3)
    )
    cols = full_to_free[3 * nodes[:, :, None] + np.arange(3)]
    vals = np.broadcast_to(weights[:, :, None], (n_pts, k, 3))
    keep = cols >= 0
    n_free = int((full_to_free >= 0).sum())
    return sp.csr_matrix(
        (vals[keep], (rows[keep], cols[keep])), shape=(3 * n_pts, n_free)
    )

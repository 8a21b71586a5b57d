"""Closest points on a body's surface, and whether points lie in the body.

:func:`closest_on_triangles` is the vectorised point-triangle test (every
point against every triangle); :func:`project_to_surface` snaps points to the
nearest boundary facet of a :class:`~idbench_fem.bodies.mesh.SolidMesh`;
:func:`inside` tests points against its tets.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from idbench_fem.bodies.mesh import SolidMesh

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def closest_on_triangles(
    points: FloatArray, triangles: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Closest point of each triangle to each point (Ericson, Real-Time CD 5.1.5).

    Parameters
    ----------
    points
        (P, 3).
    triangles
        Triangle corners (F, 3, 3): ``triangles[f, i]`` is corner i of
        triangle f.

    Returns
    -------
    closest, bary
        (P, F, 3) points and (P, F, 3) barycentric coordinates.
    """
    tri = triangles
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac = b - a, c - a
    ap = points[:, None, :] - a
    d1, d2 = np.einsum("fi,pfi->pf", ab, ap), np.einsum("fi,pfi->pf", ac, ap)
    bp = points[:, None, :] - b
    d3, d4 = np.einsum("fi,pfi->pf", ab, bp), np.einsum("fi,pfi->pf", ac, bp)
    cp = points[:, None, :] - c
    d5, d6 = np.einsum("fi,pfi->pf", ab, cp), np.einsum("fi,pfi->pf", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v, w = vb / denom, vc / denom  # interior
        cases = [  # (condition, v, w), later ones win
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), 0.0, d2 / (d2 - d6)),  # edge ac
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), d1 / (d1 - d3), 0.0),  # edge ab
            (
                (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),
                1 - (d4 - d3) / ((d4 - d3) + (d5 - d6)),
                (d4 - d3) / ((d4 - d3) + (d5 - d6)),
            ),  # edge bc
            ((d6 >= 0) & (d5 <= d6), 0.0, 1.0),  # vertex c
            ((d3 >= 0) & (d4 <= d3), 1.0, 0.0),  # vertex b
            ((d1 <= 0) & (d2 <= 0), 0.0, 0.0),  # vertex a
        ]
        for cond, cv, cw in cases:
            v = np.where(cond, cv, v)
            w = np.where(cond, cw, w)
    bary = np.stack([1.0 - v - w, v, w], axis=-1)
    return np.einsum("pfk,fki->pfi", bary, tri), bary


def project_to_surface(
    mesh: SolidMesh, points: FloatArray, chunk: int = 64
) -> tuple[FloatArray, IntArray, FloatArray, FloatArray]:
    """Nearest surface point of each point.

    Returns
    -------
    closest, facet, bary, distance
        (P, 3) points, (P,) boundary facet indices, (P, 3) barycentric
        coordinates on that facet, (P,) distances.
    """
    points = np.atleast_2d(np.asarray(points, dtype=float))
    tri = mesh.points[mesh.facets]
    out = np.empty_like(points)
    facet = np.empty(len(points), dtype=np.int64)
    bary = np.empty((len(points), 3))
    for s in range(0, len(points), chunk):
        q, b = closest_on_triangles(points[s : s + chunk], tri)
        d = np.linalg.norm(q - points[s : s + chunk, None, :], axis=2)
        j = d.argmin(axis=1)
        rows = np.arange(len(j))
        out[s : s + chunk], facet[s : s + chunk] = q[rows, j], j
        bary[s : s + chunk] = b[rows, j]
    return out, facet, bary, np.linalg.norm(out - points, axis=1)


def inside(mesh: SolidMesh, points: FloatArray) -> NDArray[np.bool_]:
    """Whether each point lies in the body (in some tet, to round-off)."""
    from scipy.spatial import cKDTree

    from idbench_fem.fem.interpolation import barycentric

    points = np.atleast_2d(np.asarray(points, dtype=float))
    x = mesh.points[mesh.tets]
    centroids = x.mean(axis=1)
    radius = np.linalg.norm(x - centroids[:, None], axis=2).max()
    result = np.zeros(len(points), dtype=bool)
    tree = cKDTree(centroids)
    for i, cand in enumerate(tree.query_ball_point(points, radius)):
        if cand:
            lam = barycentric(np.broadcast_to(points[i], (len(cand), 3)), x[cand])
            result[i] = bool((lam.min(axis=1) >= -1e-9).any())
    return result

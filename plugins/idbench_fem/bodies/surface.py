"""Closest points on a body's surface, and whether points lie in the body.

:func:`project_to_surface` snaps points (tested against every triangle with the
core's :func:`idbench.closest_on_triangles`) to the nearest boundary facet of a
:class:`~idbench_fem.bodies.mesh.SolidMesh`; :func:`inside` tests points against
its tets.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from idbench import closest_on_triangles
from idbench_fem.bodies.mesh import SolidMesh

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


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
    n = len(tri)
    for s in range(0, len(points), chunk):
        some = points[s : s + chunk]
        rep = np.repeat(some, n, axis=0)
        flat, b = closest_on_triangles(rep, *(np.tile(tri[:, i], (len(some), 1))
                                              for i in range(3)))  # fmt: skip
        q, b = flat.reshape(len(some), n, 3), b.reshape(len(some), n, 3)
        d = np.linalg.norm(q - some[:, None, :], axis=2)
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

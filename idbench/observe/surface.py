r"""Distances to a model's deformed surface: the residual of a point cloud.

Each point's signed distance to the model's deformed surface
(``model.surface(state)`` -> vertices (V, 3), triangles (T, 3);
:func:`surface_of`), point-to-plane: the distance to the plane of the
triangle whose centroid is nearest to it, signed by its outward normal.
The approximation: exact where that triangle holds the closest point (or its
neighbours are coplanar), second order in the offset along the surface
otherwise (curvature x offset^2 / 2); it is smooth in the state, which the
filters' sigma-point and finite-difference derivatives want. Asking for
``candidates`` > 1 takes instead the exact closest point among that many
nearest-centroid triangles (:func:`closest_on_triangles`). A ``gate`` clips
the distances (:func:`point_to_surface`).

The nearest centroids (the data association) are exact at every state, and
found cheaply (:class:`Association`): what is fixed per frame is a
*reference*, the centroids :math:`c^0` of the first state the frame is
evaluated at, with each point's nearest centroid :math:`j_i` and the
distance :math:`b_i` to its second-nearest, from one KD-tree query. At any
other state, with centroids :math:`c` and :math:`\delta = \max_t \lVert
c_t - c^0_t \rVert`, every other centroid is at least :math:`b_i - \delta`
from :math:`p_i` (triangle inequality), so :math:`\lVert p_i - c_{j_i}
\rVert < b_i - \delta` certifies that :math:`j_i` is still the nearest; only
the points it does not certify are queried, on a KD-tree of :math:`c`. The
triangles, hence h(x), are those a fresh query would give, whichever state
came first: deterministic and history-independent (the order changes the
cost only; exact distance ties aside), and bitwise the residual of a fresh
query (``point_to_surface(..., reuse=False)``).

A recording's held-out points are scored the same way, by their distance to
the estimated model's surface (:func:`heldout_points_mm`).
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from idbench.core.capabilities import member
from idbench.core.interfaces import FloatArray, ForwardModel

CANDIDATES = 1
"""Default triangles per point in :func:`point_to_surface` (1: point-to-plane)."""


def surface_of(model: ForwardModel, state: FloatArray) -> tuple[FloatArray, Any]:
    """``model.surface(state)`` checked: vertices (V, 3) and triangles (T, 3)."""
    surface = member(model, "surface")
    if surface is None:
        raise ValueError(
            f"observe cloud: model {type(model).__name__} has no surface(state)"
        )
    vertices, triangles = surface(state)
    return np.asarray(vertices, dtype=float), np.asarray(triangles, dtype=np.int64)


def closest_on_triangles(
    p: FloatArray, a: FloatArray, b: FloatArray, c: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Closest point to each p on triangle (a, b, c), and its barycentric weights.

    Ericson's region tests (Real-Time Collision Detection, 5.1.5), vectorised:
    each row of ``p`` with the triangle of the same row (to test every point
    against every triangle, repeat the points and tile the triangles).

    Parameters
    ----------
    p, a, b, c
        (M, 3) points and triangle corners.

    Returns
    -------
    closest, bary
        (M, 3) closest points and (M, 3) weights of a, b and c (the closest
        point is a vertex itself where the weights are 1, 0, 0).
    """
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    bp = p - b
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    cp = p - c
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        v = vb * denom
        w = vc * denom
        out = a + ab * v[:, None] + ac * w[:, None]  # inside the face
        # edges, then vertices (later assignments win: vertices last)
        t_ab = d1 / (d1 - d3)
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        out[m] = (a + ab * t_ab[:, None])[m]
        v, w = np.where(m, t_ab, v), np.where(m, 0.0, w)
        t_ac = d2 / (d2 - d6)
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        out[m] = (a + ac * t_ac[:, None])[m]
        v, w = np.where(m, 0.0, v), np.where(m, t_ac, w)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        m = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        out[m] = (b + (c - b) * t_bc[:, None])[m]
        v, w = np.where(m, 1.0 - t_bc, v), np.where(m, t_bc, w)
    for m, cv, cw, corner in (
        ((d1 <= 0) & (d2 <= 0), 0.0, 0.0, a),
        ((d3 >= 0) & (d4 <= d3), 1.0, 0.0, b),
        ((d6 >= 0) & (d5 <= d6), 0.0, 1.0, c),
    ):
        out[m] = corner[m]
        v, w = np.where(m, cv, v), np.where(m, cw, w)
    return out, np.stack([1.0 - v - w, v, w], axis=-1)


def point_to_surface(
    points: FloatArray,
    vertices: FloatArray,
    triangles: NDArray[np.int64],
    gate: float = np.inf,
    candidates: int = CANDIDATES,
    reuse: bool = True,
) -> FloatArray:
    """Signed distance (N,) of ``points`` to the surface, clipped to +- ``gate``.

    ``candidates`` = 1 (default): point-to-plane, the signed distance to the
    plane of the triangle whose centroid is nearest: smooth in the state,
    exact where that triangle holds the closest point or its neighbours are
    coplanar, second order in the tangential offset otherwise. The nearest
    centroids come from :class:`Association` (``reuse``, default: a
    :class:`scipy.spatial.cKDTree` query only where the frame's earlier
    association cannot be certified; the same triangles as a fresh query)
    or, ``reuse=False``, from a fresh query on the deformed centroids.
    More: the exact closest point on that many nearest-centroid triangles,
    signed by the closest one's normal (positive outside).
    """
    p0 = vertices[triangles[:, 0]]
    p1 = vertices[triangles[:, 1]]
    p2 = vertices[triangles[:, 2]]
    k = min(int(candidates), len(triangles))
    centroids = (p0 + p1 + p2) / 3
    if k == 1:
        if reuse:
            j1 = association(points, triangles).nearest(centroids)
        else:
            _, j1 = _tree(centroids).query(points)
        normal = np.cross(p1 - p0, p2 - p0)
        normal /= np.linalg.norm(normal, axis=1)[:, None]
        return np.clip(_dot(points - p0[j1], normal[j1]), -gate, gate)
    _, j = _tree(centroids).query(points, k=k)
    j = np.asarray(j).reshape(len(points), k)
    flat = j.ravel()
    rep = np.repeat(points, k, axis=0)
    q, _ = closest_on_triangles(rep, p0[flat], p1[flat], p2[flat])
    dist = np.linalg.norm(rep - q, axis=1).reshape(-1, k)
    best = np.argmin(dist, axis=1)
    rows = np.arange(len(points))
    tri = j[rows, best]
    qb = q.reshape(-1, k, 3)[rows, best]
    normal = np.cross(p1[tri] - p0[tri], p2[tri] - p0[tri])
    sign = np.where(_dot(points - qb, normal) < 0, -1.0, 1.0)
    return np.clip(sign * dist[rows, best], -gate, gate)


def point_to_surface_jacobian(
    points: FloatArray,
    vertices: FloatArray,
    triangles: NDArray[np.int64],
    gate: float = np.inf,
) -> Any:
    r"""D :func:`point_to_surface` (point-to-plane) / d vertices, sparse (N, 3V).

    Point i's distance is to the plane of its nearest-centroid triangle
    (a, b, c), d = (p - a) . n. Moving the vertices by delta changes it, to
    first order, by

    .. math::

        \delta d = -n \cdot (\beta_a \delta_a + \beta_b \delta_b
        + \beta_c \delta_c),

    beta the barycentric coordinates (in the triangle's plane, possibly
    outside [0, 1]) of the foot q = p - d n: the normal's rotation
    contributes through beta (n' . (x' - a') = 0 for every vertex). A point
    whose distance the ``gate`` clips has a zero row. Columns are
    ``3 v + c`` for vertex v, component c; the same triangles as
    :func:`point_to_surface` with ``candidates = 1``.
    """
    import scipy.sparse as sp

    p0 = vertices[triangles[:, 0]]
    p1 = vertices[triangles[:, 1]]
    p2 = vertices[triangles[:, 2]]
    centroids = (p0 + p1 + p2) / 3
    j = association(points, triangles).nearest(centroids)
    a, e1, e2 = p0[j], p1[j] - p0[j], p2[j] - p0[j]
    normal = np.cross(e1, e2)
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    d = _dot(points - a, normal)
    q = points - d[:, None] * normal - a
    g11, g12, g22 = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
    r1, r2 = _dot(q, e1), _dot(q, e2)
    det = g11 * g22 - g12 * g12
    beta_b = (g22 * r1 - g12 * r2) / det
    beta_c = (g11 * r2 - g12 * r1) / det
    beta = np.stack([1.0 - beta_b - beta_c, beta_b, beta_c], axis=1)  # (N, 3)
    live = np.abs(d) < gate
    values = -(beta[:, :, None] * normal[:, None, :])  # (N, 3 vertices, 3)
    values[~live] = 0.0
    cols = 3 * triangles[j][:, :, None] + np.arange(3)
    rows = np.broadcast_to(np.arange(len(points))[:, None, None], cols.shape)
    return sp.csr_matrix(
        (values.ravel(), (rows.ravel(), cols.ravel())),
        shape=(len(points), 3 * len(vertices)),
    )


def _tree(centroids: FloatArray) -> cKDTree:
    return cKDTree(centroids, balanced_tree=False, compact_nodes=False)


class Association:
    r"""The nearest-centroid triangle of each of a frame's points, at any state.

    Built at the first state the frame is evaluated at (the reference,
    centroids :math:`c^0`): one KD-tree query gives each point's
    :attr:`KEPT` nearest centroids and the distance :math:`b_i` to the next
    one. At another state (centroids :math:`c`), with
    :math:`\delta = \max_t \lVert c_t - c^0_t \rVert` the largest centroid
    move, every centroid not kept is at least :math:`b_i - \delta` from
    point :math:`p_i`; so where the nearest kept one is nearer than that (by
    a rounding margin) it is the nearest of all, certified, with no query.
    The other points are queried on a KD-tree of :math:`c`, exactly as
    without reuse. The triangles are therefore those of a fresh query at
    every state (history-independent: which state came first changes the
    cost, not the result; exact ties aside); a state where most points are
    not certified becomes the new reference.

    Parameters
    ----------
    points
        The frame's points (N, 3).
    triangles
        The surface's triangles (T, 3).
    """

    MARGIN = 1e-9
    """Relative rounding margin of the certificate."""
    KEPT = 1
    """Nearest centroids kept per point at the reference (candidates)."""
    REFERENCE_AGAIN = 0.5
    """Fraction of uncertified points past which a state becomes the reference."""

    def __init__(self, points: FloatArray, triangles: NDArray[np.int64]) -> None:
        self.points = np.array(points, dtype=float)
        self.triangles = np.array(triangles, dtype=np.int64)
        self._reference: tuple[FloatArray, NDArray[np.int64], FloatArray] | None = None
        """(centroids, nearest, second-nearest distance), replaced as one."""
        self.queries = 0
        """KD-tree queries made (for tests and benchmarks)."""

    def matches(self, points: FloatArray, triangles: NDArray[np.int64]) -> bool:
        """Whether this association is of these points and triangles."""
        return (
            np.array_equal(points, self.points)
            and np.array_equal(triangles, self.triangles)
        )  # fmt: skip

    def nearest(self, centroids: FloatArray) -> NDArray[np.int64]:
        """The index (N,) of each point's nearest centroid among ``centroids``."""
        ref = self._reference
        if ref is None or len(self.triangles) <= self.KEPT:
            return self._refer(centroids)
        reference, kept, bound = ref
        move = centroids - reference
        delta = math.sqrt(float(np.max(_dot(move, move))))
        rows = np.arange(len(self.points))
        gap = self.points[:, None, :] - centroids[kept]
        d2 = np.einsum("ijk,ijk->ij", gap, gap)
        best = np.argmin(d2, axis=1)
        d = np.sqrt(d2[rows, best])
        bad = ~(bound - delta - d > self.MARGIN * (bound + delta))
        out = kept[rows, best]
        n_bad = int(np.count_nonzero(bad))
        if n_bad == 0:
            return out
        if n_bad > self.REFERENCE_AGAIN * len(self.points):
            return self._refer(centroids)
        _, out[bad] = _tree(centroids).query(self.points[bad])
        self.queries += 1
        return out

    def _refer(self, centroids: FloatArray) -> NDArray[np.int64]:
        """Make ``centroids`` the reference: the KEPT + 1 nearest of each point."""
        k = min(self.KEPT + 1, len(centroids))
        dist, j = _tree(centroids).query(self.points, k=k)
        self.queries += 1
        dist = np.asarray(dist).reshape(len(self.points), k)
        j = np.asarray(j).reshape(len(self.points), k).astype(np.int64)
        if k > self.KEPT:
            self._reference = (np.array(centroids), j[:, :-1], dist[:, -1])
        return j[:, 0].copy()


_ASSOCIATIONS: OrderedDict[int, Association] = OrderedDict()
_LOCK = threading.Lock()
ASSOCIATIONS_KEPT = 64
"""Frames whose association is kept (least recently used dropped first)."""


def association(points: FloatArray, triangles: NDArray[np.int64]) -> Association:
    """The :class:`Association` of ``points`` on ``triangles`` (kept per frame).

    Kept by the identity of the ``points`` array and checked against its
    content and the triangles, so a changed or reused array gets a new one.
    """
    key = id(points)
    with _LOCK:
        found = _ASSOCIATIONS.get(key)
        if found is not None and found.matches(points, triangles):
            _ASSOCIATIONS.move_to_end(key)
            return found
        made = Association(points, triangles)
        _ASSOCIATIONS[key] = made
        _ASSOCIATIONS.move_to_end(key)
        while len(_ASSOCIATIONS) > ASSOCIATIONS_KEPT:
            _ASSOCIATIONS.popitem(last=False)
        return made


HELDOUT_CANDIDATES = 8
"""Nearest-centroid triangles searched for a held-out point's closest point."""


def heldout_points_mm(model: ForwardModel, state: FloatArray, points: Any) -> float:
    """Mean distance (mm) of held-out points to ``model``'s deformed surface.

    ``points`` (N, 3), positions in model coordinates (m), without
    correspondence; NaN rows (a frame with fewer points) are left out. The
    distance is to the closest point on the :data:`HELDOUT_CANDIDATES`
    triangles of nearest centroid (:func:`point_to_surface`, not gated):
    what the model's surface at ``state`` misses of a surface nobody gave
    the estimator. NaN if no point is finite or the model has no surface.
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    seen = np.isfinite(pts).all(axis=1)
    if not seen.any() or member(model, "surface") is None:
        return float("nan")
    vertices, triangles = surface_of(model, state)
    d = point_to_surface(pts[seen], vertices, triangles, candidates=HELDOUT_CANDIDATES)
    return float(1000.0 * np.abs(d).mean())


def _dot(a: FloatArray, b: FloatArray) -> FloatArray:
    return np.einsum("ij,ij->i", a, b)

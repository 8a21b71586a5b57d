r"""A virtual depth camera: the ``cloud`` observation model.

Sensing (the truth, once per step): a pinhole camera of ``resolution``
pixels casts one ray through each pixel centre onto the deformed surface
(``model.surface(state)`` -> vertices (V, 3), triangles (T, 3)). Every
(triangle, pixel in its projected bounding box) pair is intersected
(Moeller-Trumbore, both faces) and a z-buffer keeps the nearest hit per
pixel, so what another part of the surface hides is never seen (occlusion,
not a normal test). The clean reading of a covered pixel is its hit depth t
along its unit ray (the hit point is origin + t ray).

Measuring (per run, through its seeded generator; common random numbers):
``holes`` drops that fraction of the covered pixels, ``points`` of the rest
are drawn (with replacement if fewer), each point moves along its ray by
N(0, sigma^2), and ``outliers`` of them (an exact count) are replaced by a
point on the same ray at a uniform fraction in [0.3, 0.95] of its depth (an
instrument in front of the organ). A frame therefore has exactly ``points``
points, without correspondence to the mesh.

Residual (the model side, any state): each point's signed distance to the
model's deformed surface, point-to-plane: the distance to the plane of the
triangle whose centroid is nearest to it, signed by its outward normal.
The approximation: exact where that triangle holds the closest point (or its
neighbours are coplanar), second order in the offset along the surface
otherwise (curvature x offset^2 / 2); it is smooth in the state, which the
filters' sigma-point and finite-difference derivatives want. Setting
``candidates`` > 1 takes instead the exact closest point among that many
nearest-centroid triangles. Outliers are gated: :math:`r_i` is clipped to
:math:`\pm g`, :math:`g = \max(\mathrm{gate}\,\sigma, \mathrm{gate\_min})`;
a clipped point has the same residual for every sigma point or ensemble
member, so it does not move a filter's estimate. The observation is y = 0
(m = ``points`` values) with noise std sigma.

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
"""

from __future__ import annotations

import dataclasses
import math
import threading
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from idbench.core.capabilities import member
from idbench.core.interfaces import FloatArray, ForwardModel

MAX_PAIRS = 20_000_000
"""Triangle-pixel pairs a rendering may test (a resolution too fine refuses)."""

CANDIDATES = 1
"""Default triangles per point in :func:`point_to_surface` (1: point-to-plane)."""


@dataclass(frozen=True)
class Cloud:
    """A depth camera on the deformed surface; settings are realism knobs.

    Attributes
    ----------
    points
        Points per frame N (the observation size), >= 1.
    resolution
        Camera pixels (width, height).
    fov
        Vertical field of view, degrees in (0, 180).
    position, look_at
        Camera pose in model coordinates; None: ``look_at`` the centre of the
        unloaded body's bounding box, ``position`` at ``distance`` diagonals
        from it along ``direction``.
    direction
        From the target towards the camera, when ``position`` is None.
    distance
        Camera distance in bounding-box diagonals, when ``position`` is None.
    noise
        Noise std along the ray (model length unit); None: the run's
        ``--noise``.
    holes
        Fraction of the covered pixels dropped, in [0, 1).
    outliers
        Fraction of each frame's points made outliers, in [0, 1).
    gate, gate_min
        Residuals are clipped to +- max(gate sigma, gate_min).
    candidates
        Triangles searched per point (:func:`point_to_surface`): 1 (default)
        point-to-plane at the nearest-centroid triangle; more, the exact
        closest point among that many (slower, kinked at edges).
    """

    points: int = 500
    resolution: tuple[int, int] = (160, 120)
    fov: float = 45.0
    position: tuple[float, float, float] | None = None
    look_at: tuple[float, float, float] | None = None
    direction: tuple[float, float, float] = (0.0, -1.0, 1.0)
    distance: float = 2.0
    noise: float | None = None
    holes: float = 0.0
    outliers: float = 0.0
    gate: float = 5.0
    gate_min: float = 1e-3
    candidates: int = CANDIDATES
    requires: tuple[str, ...] = dataclasses.field(
        default=("surface",), init=False, repr=False
    )

    def __post_init__(self) -> None:
        for name in ("resolution", "position", "look_at", "direction"):
            value = getattr(self, name)
            if isinstance(value, list):
                object.__setattr__(self, name, tuple(value))
        if isinstance(self.points, bool) or not isinstance(self.points, int):
            raise ValueError(f"points = {self.points!r}: need a whole number >= 1")
        if self.points < 1:
            raise ValueError(f"points = {self.points!r}: need a whole number >= 1")
        res = self.resolution
        if not (
            isinstance(res, tuple) and len(res) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) and v >= 2
                    for v in res)
        ):  # fmt: skip
            raise ValueError(f"resolution = {res!r}: need [WIDTH, HEIGHT], each >= 2")
        if not (_num(self.fov) and 0 < self.fov < 180):
            raise ValueError(f"fov = {self.fov!r}: need degrees in (0, 180)")
        for name in ("position", "look_at", "direction"):
            value = getattr(self, name)
            if value is None and name != "direction":
                continue
            if not (isinstance(value, tuple) and len(value) == 3
                    and all(_num(v) for v in value)):  # fmt: skip
                raise ValueError(f"{name} = {value!r}: need [x, y, z], numbers")
        if not np.any(self.direction):
            raise ValueError("direction = [0, 0, 0]: need a nonzero vector")
        c = self.candidates
        if isinstance(c, bool) or not isinstance(c, int) or c < 1:
            raise ValueError(f"candidates = {c!r}: need a whole number >= 1")
        if not (_num(self.distance) and self.distance > 0):
            raise ValueError(f"distance = {self.distance!r}: need a number > 0")
        if self.noise is not None and not (_num(self.noise) and self.noise >= 0):
            raise ValueError(f"noise = {self.noise!r}: need a number >= 0 (or unset)")
        for name in ("holes", "outliers"):
            value = getattr(self, name)
            if not (_num(value) and 0 <= value < 1):
                raise ValueError(f"{name} = {value!r}: need a fraction in [0, 1)")
        for name in ("gate", "gate_min"):
            value = getattr(self, name)
            if not (_num(value) and value > 0):
                raise ValueError(f"{name} = {value!r}: need a number > 0")

    # -- the ObservationModel protocol ----------------------------------------

    def sense(
        self, model: ForwardModel, theta: FloatArray, k: int, state: FloatArray
    ) -> dict[str, FloatArray]:
        """Render the deformed surface: ``depth`` (P,), ``rays`` (P, 3), ``origin``.

        The P covered pixels' hit depth along their unit ray from the camera
        at ``origin`` (3,); the hit points are ``origin + depth * rays``.
        """
        vertices, triangles = surface_of(model, state)
        rest, _ = surface_of(model, model.reset())
        origin, look = self.pose(rest)
        _, depth, rays = render(
            vertices, triangles, origin, look, self.resolution, self.fov
        )
        if depth.size == 0:
            raise ValueError(
                f"the camera at {np.round(origin, 6).tolist()} looking at "
                f"{np.round(look, 6).tolist()} sees no part of the body at step {k} "
                "(check position, look_at, direction, fov)"
            )
        return {"depth": depth, "rays": rays, "origin": origin}

    def measure(
        self, clean: Sequence[Mapping[str, FloatArray]], rng: np.random.Generator,
        noise: float,
    ) -> list[dict[str, FloatArray]]:  # fmt: skip
        """Holes, N points per frame, noise along the ray, outliers (see module)."""
        sigma = float(noise if self.noise is None else self.noise)
        out = []
        for c in clean:
            depth, rays, origin = c["depth"], c["rays"], c["origin"]
            if depth.size == 0:
                raise ValueError(
                    "observe cloud: the camera sees no part of the body (check "
                    "position, look_at, fov)"
                )
            keep = rng.permutation(depth.size)[
                : depth.size - round(self.holes * depth.size)
            ]
            if keep.size == 0:
                keep = np.arange(depth.size)
            pick = rng.choice(keep, size=self.points, replace=keep.size < self.points)
            t = depth[pick] + sigma * rng.standard_normal(self.points)
            n_out = round(self.outliers * self.points)
            bad = rng.permutation(self.points)[:n_out]
            t[bad] = depth[pick[bad]] * rng.uniform(0.3, 0.95, n_out)
            points = origin[None, :] + t[:, None] * rays[pick]
            out.append({"points": points, "origin": origin, "sigma": np.array(sigma)})
        return out

    def values(self, frame: Any) -> FloatArray:
        """Y = 0 for every point, shape (N,)."""
        return np.zeros(len(frame.data["points"]))

    def noise_std(self, frame: Any, noise: float) -> float:
        """The sigma along the ray the frame was measured with."""
        return float(
            frame.data.get("sigma", noise if self.noise is None else self.noise)
        )

    def predict(
        self, model: ForwardModel, frame: Any, theta: FloatArray, k: int,
        state: FloatArray,
    ) -> FloatArray:  # fmt: skip
        """Gated signed distance of each point to ``model``'s deformed surface."""
        vertices, triangles = surface_of(model, state)
        sigma = self.noise_std(frame, 0.0)
        g = max(self.gate * sigma, self.gate_min)
        return point_to_surface(
            frame.data["points"], vertices, triangles, gate=g,
            candidates=self.candidates,
        )  # fmt: skip

    def identity(self) -> list[Any]:
        """Every setting but the noise sigma (it scales common draws)."""
        fields = dataclasses.asdict(self)
        fields.pop("noise")
        fields.pop("requires")
        return ["cloud", sorted((k, _plain(v)) for k, v in fields.items())]

    # -- the camera -------------------------------------------------------------

    def pose(self, rest: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Camera position and look-at point (3,), from the settings or ``rest``."""
        lo, hi = rest.min(axis=0), rest.max(axis=0)
        look = (lo + hi) / 2 if self.look_at is None else np.array(self.look_at, float)
        if self.position is not None:
            return np.array(self.position, dtype=float), look
        d = np.array(self.direction, dtype=float)
        diag = float(np.linalg.norm(hi - lo)) or 1.0
        return look + self.distance * diag * d / np.linalg.norm(d), look


def surface_of(model: ForwardModel, state: FloatArray) -> tuple[FloatArray, Any]:
    """``model.surface(state)`` checked: vertices (V, 3) and triangles (T, 3)."""
    surface = member(model, "surface")
    if surface is None:
        raise ValueError(
            f"observe cloud: model {type(model).__name__} has no surface(state)"
        )
    vertices, triangles = surface(state)
    return np.asarray(vertices, dtype=float), np.asarray(triangles, dtype=np.int64)


def camera_rays(
    origin: FloatArray, look: FloatArray, resolution: tuple[int, int], fov: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Camera basis (right, up, forward), each (3,): forward towards ``look``."""
    f = np.asarray(look, float) - np.asarray(origin, float)
    f = f / np.linalg.norm(f)
    up = np.array([0.0, 0.0, 1.0])
    if abs(f @ up) > 0.99:
        up = np.array([0.0, 1.0, 0.0])
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    return r, np.cross(r, f), f


def render(
    vertices: FloatArray,
    triangles: NDArray[np.int64],
    origin: FloatArray,
    look: FloatArray,
    resolution: tuple[int, int],
    fov: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Ray-cast every pixel onto the triangles, keep the nearest hit per pixel.

    Returns
    -------
    tuple
        Hit points (P, 3), their depth along the ray (P,) and the unit rays
        (P, 3), of the P covered pixels in row-major pixel order.
    """
    W, H = resolution
    r, u, f = camera_rays(origin, look, resolution, fov)
    ty = math.tan(math.radians(fov) / 2)
    tx = ty * W / H
    rel = vertices - origin
    z = rel @ f
    tri = triangles[np.all(z[triangles] > 1e-12, axis=1)]  # in front of the camera
    zz = z[tri]
    col = ((rel[tri] @ r) / zz / tx + 1) * W / 2 - 0.5
    row = (1 - (rel[tri] @ u) / zz / ty) * H / 2 - 0.5
    c0 = np.clip(np.ceil(col.min(axis=1)), 0, W).astype(np.int64)
    c1 = np.clip(np.floor(col.max(axis=1)), -1, W - 1).astype(np.int64)
    r0 = np.clip(np.ceil(row.min(axis=1)), 0, H).astype(np.int64)
    r1 = np.clip(np.floor(row.max(axis=1)), -1, H - 1).astype(np.int64)
    nc = np.maximum(c1 - c0 + 1, 0)
    nr = np.maximum(r1 - r0 + 1, 0)
    counts = nc * nr
    total = int(counts.sum())
    if total > MAX_PAIRS:
        raise ValueError(
            f"observe cloud: {total:,} triangle-pixel pairs at resolution {W}x{H}; "
            f"more than {MAX_PAIRS:,}: lower the resolution"
        )
    empty = np.empty((0, 3))
    if total == 0:
        return empty, np.empty(0), empty
    t_idx = np.repeat(np.arange(len(tri)), counts)
    local = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    pc = c0[t_idx] + local % nc[t_idx]
    pr = r0[t_idx] + local // nc[t_idx]
    sx = ((pc + 0.5) * 2 / W - 1) * tx
    sy = (1 - (pr + 0.5) * 2 / H) * ty
    d = f[None, :] + sx[:, None] * r[None, :] + sy[:, None] * u[None, :]
    d /= np.linalg.norm(d, axis=1)[:, None]
    v0 = vertices[tri[t_idx, 0]]
    e1 = vertices[tri[t_idx, 1]] - v0
    e2 = vertices[tri[t_idx, 2]] - v0
    pvec = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, pvec)
    ok = np.abs(det) > 1e-300
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tvec = origin[None, :] - v0
    a = np.einsum("ij,ij->i", tvec, pvec) * inv
    qvec = np.cross(tvec, e1)
    b = np.einsum("ij,ij->i", d, qvec) * inv
    t = np.einsum("ij,ij->i", e2, qvec) * inv
    hit = ok & (a >= 0) & (b >= 0) & (a + b <= 1) & (t > 0)
    pix = (pr * W + pc)[hit]
    t, d = t[hit], d[hit]
    order = np.lexsort((t, pix))
    pix, t, d = pix[order], t[order], d[order]
    first = np.ones(pix.size, dtype=bool)
    first[1:] = pix[1:] != pix[:-1]
    t, d = t[first], d[first]
    return origin[None, :] + t[:, None] * d, t, d


def closest_on_triangles(
    p: FloatArray, a: FloatArray, b: FloatArray, c: FloatArray
) -> FloatArray:
    """Closest point (M, 3) to each p on triangle (a, b, c), all (M, 3).

    Ericson's region tests (Real-Time Collision Detection, 5.1.5), vectorised.
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
        t_ac = d2 / (d2 - d6)
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        out[m] = (a + ac * t_ac[:, None])[m]
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        m = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        out[m] = (b + (c - b) * t_bc[:, None])[m]
    out[(d1 <= 0) & (d2 <= 0)] = a[(d1 <= 0) & (d2 <= 0)]
    out[(d3 >= 0) & (d4 <= d3)] = b[(d3 >= 0) & (d4 <= d3)]
    out[(d6 >= 0) & (d5 <= d6)] = c[(d6 >= 0) & (d5 <= d6)]
    return out


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
    q = closest_on_triangles(rep, p0[flat], p1[flat], p2[flat])
    dist = np.linalg.norm(rep - q, axis=1).reshape(-1, k)
    best = np.argmin(dist, axis=1)
    rows = np.arange(len(points))
    tri = j[rows, best]
    qb = q.reshape(-1, k, 3)[rows, best]
    normal = np.cross(p1[tri] - p0[tri], p2[tri] - p0[tri])
    sign = np.where(_dot(points - qb, normal) < 0, -1.0, 1.0)
    return np.clip(sign * dist[rows, best], -gate, gate)


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


def clean_points(
    cloud: Cloud, clean: Mapping[str, FloatArray], rng: np.random.Generator
) -> FloatArray:
    """``cloud.points`` noise-free points (N, 3) of a clean reading, no outliers.

    Pixels drawn without replacement where there are enough (``rng``); the
    held-out cloud of a recording (:mod:`idbench.run.record`).
    """
    depth, rays, origin = clean["depth"], clean["rays"], clean["origin"]
    n = min(cloud.points, depth.size)
    pick = rng.choice(depth.size, size=n, replace=False)
    return np.asarray(origin)[None, :] + depth[pick][:, None] * rays[pick]


def _dot(a: FloatArray, b: FloatArray) -> FloatArray:
    return np.einsum("ij,ij->i", a, b)


def _num(x: Any) -> bool:
    ok = isinstance(x, int | float) and not isinstance(x, bool)
    return ok and math.isfinite(x)


def _plain(v: Any) -> Any:
    return list(v) if isinstance(v, tuple) else v

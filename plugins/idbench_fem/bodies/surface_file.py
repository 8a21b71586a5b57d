r"""A closed triangulated surface read from a file, and what is wrong with it.

:func:`read_surface` reads an STL, OBJ or PLY file (meshio) into a
:class:`Surface`: its vertices scaled to metres, duplicates merged, its
triangles. :func:`surface_problems` says, one line each with coordinates,
why it cannot bound a body:

- *open*: edges used by one triangle only (a hole);
- *non-manifold*: edges shared by three or more triangles;
- *self-intersecting*: two triangles that cross (a fold), found before any
  meshing by :func:`crossings`.

Self-intersections are tested here rather than left to gmsh: gmsh's answer
("PLC Error: A segment and a facet intersect") comes after remeshing, at
every size, and names nodes of its own remeshed surface, not where the
input folds. The test is vectorised: candidate pairs are triangles whose
bounding spheres overlap (a :class:`scipy.spatial.cKDTree` of their
centroids), and each pair is tested by six segment-triangle intersections
(each edge of one against the other, Moller-Trumbore, touching included);
pairs sharing an edge are skipped, and a touch at the vertex two triangles
share does not count (coplanar overlaps are not detected).
"""

from __future__ import annotations

import contextlib
import io
import warnings
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

FORMATS = (".stl", ".obj", ".ply")
"""Surface files :func:`read_surface` reads."""

_EPS = 1e-9
"""Relative tolerance of the intersection tests (barycentric, along an edge)."""


@dataclass(frozen=True)
class Surface:
    """A triangulated surface: vertices (V, 3) in metres, triangles (T, 3).

    ``numbers`` (T,): each triangle's number in the file, counting from 1
    (triangles dropped as degenerate leave gaps).
    """

    path: str
    points: FloatArray
    triangles: IntArray
    numbers: IntArray

    @property
    def area(self) -> float:
        """The total area (m^2)."""
        p = self.points[self.triangles]
        return float(0.5 * np.linalg.norm(_normals(p), axis=1).sum())

    @property
    def volume(self) -> float:
        """The enclosed volume (m^3) (divergence theorem; closed surfaces)."""
        return abs(_signed_volume(self.points, oriented(self.triangles)))

    @property
    def size(self) -> float:
        """The bounding box's diagonal (m)."""
        return float(np.linalg.norm(np.ptp(self.points, axis=0)))


def _normals(p: FloatArray) -> FloatArray:
    """Normals times twice the area of triangles ``p`` (T, 3, 3)."""
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def _signed_volume(points: FloatArray, triangles: IntArray) -> float:
    p = points[triangles]
    return float(np.einsum("ti,ti->t", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6)


def read_surface(path: str | Path, scale: float = 1.0) -> Surface:
    """Read a surface file (STL, OBJ, PLY) and scale it (to metres).

    Vertices closer than 1e-9 of the bounding box's diagonal are merged (an
    STL repeats each vertex per triangle); triangles that lose a vertex to
    the merge are dropped; quads are split in two.

    Raises
    ------
    ValueError
        One line: a missing or unreadable file, another format, no
        triangles, a scale that is not a number > 0.
    """
    import meshio

    path = Path(path)
    where = f"surface {str(path)!r}"
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"--scale {scale!r}: need a number > 0 (metres per unit)")
    if path.suffix.lower() not in FORMATS:
        raise ValueError(
            f"{where}: a {path.suffix or 'suffix-less'} file; give an STL, OBJ or "
            "PLY surface (meshio converts others: meshio convert IN OUT.stl)"
        )
    if not path.is_file():
        raise ValueError(f"{where} does not exist")
    chatter = io.StringIO()
    try:
        with (
            contextlib.redirect_stdout(chatter),
            contextlib.redirect_stderr(chatter),
            warnings.catch_warnings(),
        ):
            warnings.simplefilter("ignore")  # meshio's ASCII-STL size guess
            m = meshio.read(path)
    except (Exception, SystemExit) as exc:
        why = " ".join(chatter.getvalue().split()) or f"{type(exc).__name__}: {exc}"
        raise ValueError(f"{where}: meshio cannot read it ({why})") from None
    tris = [np.asarray(c.data) for c in m.cells if c.type == "triangle"]
    quads = [np.asarray(c.data) for c in m.cells if c.type == "quad"]
    tris += [q[:, [0, 1, 2]] for q in quads] + [q[:, [0, 2, 3]] for q in quads]
    if not tris:
        kinds = sorted({c.type for c in m.cells})
        raise ValueError(f"{where} has no triangles (found {kinds or 'no cells'})")
    points = np.asarray(m.points, dtype=float)[:, :3] * float(scale)
    if not np.isfinite(points).all():
        raise ValueError(f"{where} has non-finite vertex coordinates")
    return merged(str(path), points, np.concatenate(tris).astype(np.int64))


def merged(path: str, points: FloatArray, triangles: IntArray) -> Surface:
    """A :class:`Surface` with coincident vertices merged and unused ones dropped."""
    tol = 1e-9 * float(np.linalg.norm(np.ptp(points, axis=0)) or 1.0)
    keys = np.round(points / tol).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    tri = inverse.reshape(-1)[triangles]
    keep = np.all(tri != np.roll(tri, 1, axis=1), axis=1)
    tri = tri[keep]
    used, tri = np.unique(tri, return_inverse=True)
    numbers = np.flatnonzero(keep).astype(np.int64) + 1
    return Surface(
        path, points[first][used], tri.reshape(-1, 3).astype(np.int64), numbers
    )


def edge_use(triangles: IntArray) -> tuple[IntArray, IntArray]:
    """Undirected edges (E, 2) of ``triangles`` and how many triangles use each."""
    e = np.sort(triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edges, counts = np.unique(e, axis=0, return_counts=True)
    return edges, counts


def oriented(triangles: IntArray) -> IntArray:
    """``triangles`` with a consistent orientation (each edge run both ways).

    Already consistent (the usual case): returned as is. Otherwise flipped
    triangle by triangle from a neighbour, breadth first over each connected
    piece (on manifold edges only).
    """
    directed = triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    if len(np.unique(directed, axis=0)) == len(directed):
        return triangles
    tri = np.array(triangles)
    n = len(tri)
    key = np.sort(directed, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    owners: dict[int, list[int]] = {}
    for i, e in enumerate(inverse):
        if counts[e] == 2:
            owners.setdefault(int(e), []).append(i // 3)
    neighbours: list[list[int]] = [[] for _ in range(n)]
    for a, b in owners.values():
        neighbours[a].append(b)
        neighbours[b].append(a)
    seen = np.zeros(n, dtype=bool)
    for start in range(n):
        if seen[start]:
            continue
        seen[start] = True
        queue = deque([start])
        while queue:
            t = queue.popleft()
            mine = {(int(tri[t, i]), int(tri[t, (i + 1) % 3])) for i in range(3)}
            for u in neighbours[t]:
                if seen[u]:
                    continue
                theirs = {(int(tri[u, i]), int(tri[u, (i + 1) % 3])) for i in range(3)}
                if mine & theirs:  # a shared edge run the same way: flip u
                    tri[u, [1, 2]] = tri[u, [2, 1]]
                seen[u] = True
                queue.append(u)
    return tri


def crossings(points: FloatArray, triangles: IntArray) -> tuple[IntArray, FloatArray]:
    """Pairs of triangles that cross each other, and a point of each crossing.

    Returns
    -------
    pairs, where
        (P, 2) triangle indices (i < j) and (P, 3) a point where an edge of
        one passes through the other.
    """
    from scipy.spatial import cKDTree

    p = points[triangles]
    centroids = p.mean(axis=1)
    radius = np.linalg.norm(p - centroids[:, None], axis=2).max(axis=1)
    pairs = cKDTree(centroids).query_pairs(2 * radius.max(), output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.int64), np.zeros((0, 3))
    i, j = pairs[:, 0], pairs[:, 1]
    close = np.linalg.norm(centroids[i] - centroids[j], axis=1) <= radius[i] + radius[j]
    i, j = i[close], j[close]
    same = triangles[i][:, :, None] == triangles[j][:, None, :]  # (n, 3, 3)
    shared = same.sum(axis=(1, 2))
    keep = shared < 2  # neighbours across an edge: not tested
    i, j, same, shared = i[keep], j[keep], same[keep], shared[keep]
    corner = np.full(len(i), -1, dtype=np.int64)
    one = np.flatnonzero(shared == 1)
    corner[one] = triangles[i[one]][same[one].any(axis=2)]
    tol = 1e-7 * float(np.linalg.norm(np.ptp(points, axis=0)))
    hit = np.zeros(len(i), dtype=bool)
    where = np.zeros((len(i), 3))
    for a, b in ((i, j), (j, i)):
        for k in range(3):
            start, end = p[a, k], p[a, (k + 1) % 3]
            crossed, at = _segment_hits(start, end, p[b])
            # a touch at the vertex the two share is no crossing
            at_corner = (corner >= 0) & (
                np.linalg.norm(at - points[np.maximum(corner, 0)], axis=1) <= tol
            )
            crossed &= ~at_corner
            where[crossed & ~hit] = at[crossed & ~hit]
            hit |= crossed
    order = np.lexsort((j[hit], i[hit]))
    pairs = np.stack([i[hit], j[hit]], axis=1)[order]
    return pairs.astype(np.int64), where[hit][order]


def _segment_hits(
    start: FloatArray, end: FloatArray, tri: FloatArray
) -> tuple[NDArray[np.bool_], FloatArray]:
    """Whether segments (n, 3) meet triangles (n, 3, 3) (Moller-Trumbore).

    Touching counts (an end on the triangle, a crossing on its edge), to a
    relative tolerance; also the meeting points (n, 3).
    """
    d = end - start
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    h = np.cross(d, e2)
    det = np.einsum("ni,ni->n", e1, h)
    scale = np.prod([np.linalg.norm(w, axis=1) for w in (d, e1, e2)], axis=0)
    ok = np.abs(det) > 1e-12 * scale
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = start - tri[:, 0]
    u = inv * np.einsum("ni,ni->n", s, h)
    q = np.cross(s, e1)
    v = inv * np.einsum("ni,ni->n", d, q)
    t = inv * np.einsum("ni,ni->n", e2, q)
    inside = (u >= -_EPS) & (v >= -_EPS) & (u + v <= 1 + _EPS)
    along = (t >= -_EPS) & (t <= 1 + _EPS)
    return ok & inside & along, start + t[:, None] * d


def _at(x: FloatArray) -> str:
    """Coordinates for a message, in metres."""
    return "(" + ", ".join(f"{v:.4g}" for v in x) + ") m"


def surface_problems(surface: Surface) -> list[str]:
    """Why ``surface`` cannot bound a body, one line each (empty: nothing).

    Each line names the file, what is wrong, how often, and where (the
    coordinates of an offending edge or crossing), and what to do.
    """
    where = f"surface {surface.path!r}"
    x, tri = surface.points, surface.triangles
    out = []
    edges, counts = edge_use(tri)
    for bad, what, fix in (
        (edges[counts == 1], "is open: {n} edge(s) belong to one triangle only",
         "close its holes (a surface must enclose the body)"),
        (edges[counts > 2],
         "is not manifold: {n} edge(s) are shared by more than two triangles",
         "split the touching pieces or export one closed body"),
    ):  # fmt: skip
        if len(bad):
            a, b = x[bad[0]]
            out.append(
                f"{where} {what.format(n=len(bad))}, e.g. from {_at(a)} to "
                f"{_at(b)}; {fix}"
            )
    pairs, at = crossings(x, tri)
    if len(pairs):
        i, j = pairs[0]
        out.append(
            f"{where} crosses itself: {len(pairs)} pair(s) of triangles intersect, "
            f"e.g. triangles {surface.numbers[i]} and {surface.numbers[j]} of the "
            f"file near {_at(at[0])}; re-sample or "
            "smooth the surface there (see the body reference: a fold)"
        )
    return out

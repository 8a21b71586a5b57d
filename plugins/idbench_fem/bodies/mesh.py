"""A general tetrahedral body: its nodes, tets, boundary and named sets.

:func:`read_mesh` reads any tetrahedral mesh meshio reads (gmsh .msh with
physical groups, .vtu, .xdmf, ...) into a :class:`SolidMesh`: positively
oriented tets, the outward-oriented boundary triangles, and the named sets of
the file (meshio ``cell_sets`` from gmsh physical groups or cell sets, and
``point_sets``); :func:`from_arrays` builds one from arrays. Regions are
turned into nodes or boundary facets in :mod:`idbench_fem.bodies.regions`;
closest points on the surface are in :mod:`idbench_fem.bodies.surface`.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_OTHER_SOLIDS = {
    "hexahedron", "hexahedron20", "hexahedron24", "hexahedron27", "wedge",
    "wedge15", "pyramid", "pyramid13", "pyramid14", "tetra10", "tetra20",
}  # fmt: skip
"""Volume cells other than linear tets (a mesh mixing them in is refused)."""

_LOCAL_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
"""Faces of a positively oriented tet, outward normals by the right-hand rule."""


@dataclass(frozen=True, eq=False)
class SolidMesh:
    """Linear tetrahedra with named regions and an oriented boundary.

    Attributes
    ----------
    path
        Where it was read from (for messages).
    points
        Node coordinates (N, 3).
    tets
        Connectivity (T, 4), positively oriented.
    facets
        Boundary triangles (F, 3), outward normals by the right-hand rule.
    facet_tets
        The tet each boundary facet belongs to, (F,).
    cell_sets
        Name -> tet indices, from the file's volume groups.
    facet_sets
        Name -> boundary facet indices, from the file's surface groups (and
        the boundary facets of volume groups).
    node_sets
        Name -> node indices, for every named set (its cells' nodes) and the
        file's point sets.
    surface_names
        The names given as surface groups (triangles) or point sets; a name
        only in ``cell_sets`` is a volume, whose facet set is its boundary.
    """

    path: str
    points: FloatArray
    tets: IntArray
    facets: IntArray
    facet_tets: IntArray
    cell_sets: dict[str, IntArray] = field(default_factory=dict)
    facet_sets: dict[str, IntArray] = field(default_factory=dict)
    node_sets: dict[str, IntArray] = field(default_factory=dict)
    surface_names: frozenset[str] = frozenset()

    def volume_only(self, name: str) -> bool:
        """Whether ``name`` is a volume region with no surface group of that name."""
        return name in self.cell_sets and name not in self.surface_names

    @property
    def label(self) -> str:
        """The mesh for messages: its file and node count, ``'a.msh' (975 nodes)``."""
        return f"{self.path!r} ({len(self.points)} nodes)"

    @property
    def names(self) -> list[str]:
        """All region names, sorted."""
        return sorted(set(self.cell_sets) | set(self.facet_sets) | set(self.node_sets))

    @property
    def volumes(self) -> FloatArray:
        """Tet volumes (T,)."""
        x = self.points[self.tets]
        return _det(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]) / 6.0

    def facet_areas(self, facets: IntArray | None = None) -> FloatArray:
        """Areas of boundary facets (all, or those indexed), (F,)."""
        return 0.5 * np.linalg.norm(self.facet_normals(facets), axis=1)

    def facet_normals(self, facets: IntArray | None = None) -> FloatArray:
        """Outward normals scaled by twice the area, (F, 3)."""
        tri = self.facets if facets is None else self.facets[facets]
        p = self.points[tri]
        return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])

    @property
    def surface_nodes(self) -> IntArray:
        """Nodes on the boundary, increasing."""
        return np.unique(self.facets)

    @property
    def lower(self) -> FloatArray:
        """Lower corner of the bounding box, (3,)."""
        return np.asarray(self.points.min(axis=0))

    @property
    def upper(self) -> FloatArray:
        """Upper corner of the bounding box, (3,)."""
        return np.asarray(self.points.max(axis=0))

    def digest(self) -> str:
        """SHA-256 of the node coordinates and the connectivity."""
        h = hashlib.sha256()
        h.update(np.ascontiguousarray(self.points, dtype="<f8").tobytes())
        h.update(np.ascontiguousarray(self.tets, dtype="<i8").tobytes())
        return h.hexdigest()


def _det(a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
    return np.einsum("ti,ti->t", a, np.cross(b, c))


def tet_quality(points: FloatArray, tets: IntArray) -> FloatArray:
    r"""The mean-ratio quality of each tet (T,): 1 regular, 0 flat.

    .. math:: q = 12\, (3 |V|)^{2/3} / \sum_{i<j} l_{ij}^2
    """
    x = points[tets]
    volume = np.abs(_det(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0])) / 6
    pairs = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
    lengths = sum(((x[:, i] - x[:, j]) ** 2).sum(axis=1) for i, j in pairs)
    return np.asarray(12.0 * np.cbrt(3.0 * volume) ** 2 / lengths)


def check_not_folded(
    points: NDArray[np.float64], tets: NDArray[np.int64], spec: str
) -> None:
    """Raise ValueError if tetrahedra overlap their neighbours (inverted elements).

    Vertex order is not a test of inversion (the tets were just re-oriented):
    a tet is inverted when it lies on the same side of a shared face as its
    neighbour, i.e. the two vertices opposite an interior face are not on
    opposite sides of it, or a face is shared by more than two tets.
    """
    local = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])
    faces = np.sort(tets[:, local].reshape(-1, 3), axis=1)
    opposite = tets.reshape(-1)
    p0, p1, p2 = (points[faces[:, i]] for i in range(3))
    side = np.sign(
        np.einsum("fi,fi->f", np.cross(p1 - p0, p2 - p0), points[opposite] - p0)
    )
    n = len(points)
    keys = faces if n >= 2**21 else (faces[:, 0] * n + faces[:, 1]) * n + faces[:, 2]
    _, inverse, counts = np.unique(
        keys, axis=0, return_inverse=True, return_counts=True
    )
    inverse = inverse.reshape(-1)
    balance = np.bincount(inverse, weights=side)
    bad_face = (counts > 2) | ((counts == 2) & (balance != 0))
    if np.any(bad_face):
        bad = np.unique(np.flatnonzero(bad_face[inverse]) // 4)
        raise ValueError(
            f"mesh {spec!r}: has inverted tetrahedra ({len(bad)} overlap a "
            f"neighbour, e.g. tetrahedron {int(bad[0])}); fix or remesh it"
        )


def check_connected(n_points: int, tets: NDArray[np.int64], spec: str) -> None:
    """Raise ValueError if the tets form more than one piece (sharing no node).

    A body in disconnected pieces has a singular stiffness (a piece without a
    clamp floats) or is not the body meant; nodes no tet uses must be dropped
    before (they would count as pieces).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows = np.repeat(tets[:, 0], 3)
    cols = tets[:, 1:].reshape(-1)
    graph = coo_matrix(
        (np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n_points,) * 2
    )
    pieces, _ = connected_components(graph, directed=False)
    if pieces > 1:
        raise ValueError(
            f"mesh {spec!r}: is in {pieces} disconnected pieces (no node joins "
            "them); a body must be one connected piece of tetrahedra"
        )


def extent(
    points: NDArray[np.float64], tets: NDArray[np.int64]
) -> tuple[NDArray[np.float64], float]:
    """The bounding box (2, 3) (lower, upper corner) and the volume of a mesh.

    What a model exposes as ``bounds`` and ``volume``, so that the core can
    refuse a truth of another body than the model meshes.
    """
    x = points[tets]
    det = np.einsum(
        "ti,ti->t", x[:, 1] - x[:, 0], np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 0])
    )
    bounds = np.array([points.min(axis=0), points.max(axis=0)])
    return bounds, float(np.abs(det).sum() / 6.0)


def from_arrays(
    points: FloatArray,
    tets: IntArray,
    path: str = "<arrays>",
    cell_sets: dict[str, IntArray] | None = None,
    triangle_sets: dict[str, IntArray] | None = None,
    point_sets: dict[str, IntArray] | None = None,
) -> SolidMesh:
    """Build a :class:`SolidMesh`: orient tets, find the boundary, map the sets.

    Parameters
    ----------
    points, tets
        (N, 3) and (T, 4); nodes no tet uses are dropped (and renumbered).
    cell_sets
        Name -> tet indices.
    triangle_sets
        Name -> triangles as node triples (K, 3); only boundary ones are kept.
    point_sets
        Name -> node indices.

    Raises
    ------
    ValueError
        No tets, degenerate or inverted tets, bad indices.
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    tets = np.array(tets, dtype=np.int64)
    if tets.ndim != 2 or tets.shape[1] != 4 or len(tets) == 0:
        raise ValueError(
            f"mesh {path!r} has no tetrahedra; a solid needs 'tetra' cells"
        )
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"mesh {path!r}: points must have shape (N, 3)")
    if not np.isfinite(points).all():
        raise ValueError(f"mesh {path!r}: has non-finite node coordinates")
    outside = (tets < 0) | (tets >= len(points))
    if outside.any():
        raise ValueError(
            f"mesh {path!r}: a tetrahedron refers to node {int(tets[outside][0])}, "
            f"but the nodes are numbered 0..{len(points) - 1}"
        )
    used = np.unique(tets)
    remap = np.full(len(points), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    points, tets = points[used], remap[tets]
    x = points[tets]
    det = _det(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0])
    scale = float(np.max(np.ptp(points, axis=0)))
    flat = np.abs(det) <= 1e-12 * scale**3
    if flat.any():
        raise ValueError(
            f"mesh {path!r} has {int(flat.sum())} degenerate (zero-volume) "
            f"tetrahedra, e.g. tetrahedron {int(np.argmax(flat))}"
        )
    flip = det < 0
    tets[flip, 2], tets[flip, 3] = tets[flip, 3].copy(), tets[flip, 2].copy()
    check_not_folded(points, tets, path)
    check_connected(len(points), tets, path)

    faces = tets[:, _LOCAL_FACES].reshape(-1, 3)
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    on_boundary = np.flatnonzero(counts[inverse.reshape(-1)] == 1)
    facets = faces[on_boundary]
    facet_tets = on_boundary // 4

    n_nodes = len(points)
    cells = {
        k: np.unique(np.asarray(v, dtype=np.int64))
        for k, v in (cell_sets or {}).items()
    }
    facet_sets: dict[str, IntArray] = {}
    node_sets: dict[str, IntArray] = {}
    lookup = {tuple(k): i for i, k in enumerate(np.sort(facets, axis=1).tolist())}
    for name, tri in (triangle_sets or {}).items():
        tri = remap[np.asarray(tri, dtype=np.int64).reshape(-1, 3)]
        found = [lookup.get(tuple(k)) for k in np.sort(tri, axis=1).tolist()]
        facet_sets[name] = np.array(
            sorted({f for f in found if f is not None}), dtype=np.int64
        )
        node_sets[name] = np.unique(tri[tri >= 0])
    for name, idx in cells.items():
        in_set = np.zeros(len(tets), dtype=bool)
        in_set[idx] = True
        facet_sets.setdefault(name, np.flatnonzero(in_set[facet_tets]))
        node_sets[name] = np.unique(tets[idx])
    for name, idx in (point_sets or {}).items():
        nodes = remap[np.asarray(idx, dtype=np.int64)]
        node_sets[name] = np.unique(nodes[nodes >= 0])
        if name not in facet_sets:
            inside = np.zeros(n_nodes, dtype=bool)
            inside[node_sets[name]] = True
            facet_sets[name] = np.flatnonzero(inside[facets].all(axis=1))
    surface_names = frozenset({*(triangle_sets or {}), *(point_sets or {})})
    return SolidMesh(
        path, points, tets, facets, facet_tets, cells, facet_sets, node_sets,
        surface_names,
    )  # fmt: skip


def conversion_hint(path: Path) -> str:
    """What to do with a mesh file meshio cannot read: how to convert it.

    A legacy gmsh (v1) file, which starts with ``$NOD``, is named as one.
    """
    import shlex

    command = (
        f"gmsh {shlex.quote(str(path))} -save -format msh22 -o "
        f"{shlex.quote(str(path.with_name(path.stem + '-v22.msh')))}"
    )
    with contextlib.suppress(OSError):
        with path.open("rb") as f:
            head = f.read(64).lstrip()
        if head.startswith((b"$NOD", b"$PTS")):
            return (
                "it is a legacy gmsh v1 mesh: convert it with the gmsh installed "
                f"with idbench: {command}"
            )
    return (
        "convert it to a format meshio reads (gmsh 2.2 or 4.1 .msh, .vtu, "
        f".xdmf), e.g. {command} (or meshio convert IN OUT.vtu)"
    )


def read_mesh(path: str | Path) -> SolidMesh:
    """Read a tetrahedral mesh file with meshio, keeping its named sets.

    Raises
    ------
    ValueError
        Unreadable file, no tets, degenerate or inverted tets.
    """
    import meshio

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"mesh file {str(path)!r} does not exist")
    chatter = io.StringIO()
    try:
        with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
            m = meshio.read(path)
    except (Exception, SystemExit) as exc:
        why = " ".join(chatter.getvalue().split()) or f"{type(exc).__name__}: {exc}"
        raise ValueError(
            f"mesh file {str(path)!r}: meshio cannot read it ({why}); "
            + conversion_hint(path)
        ) from None
    offsets: dict[int, int] = {}
    tets = []
    n = 0
    for i, block in enumerate(m.cells):
        if block.type == "tetra":
            offsets[i] = n
            n += len(block.data)
            tets.append(block.data)
    kinds = sorted({c.type for c in m.cells})
    if not tets:
        raise ValueError(
            f"mesh file {str(path)!r} has no 'tetra' cells (found {kinds}); "
            "a solid needs linear tetrahedra"
        )
    if others := sorted(set(kinds) & _OTHER_SOLIDS):
        raise ValueError(
            f"mesh file {str(path)!r} mixes tetrahedra with {others} cells; "
            "only linear tetrahedra are supported"
        )
    cell_sets: dict[str, IntArray] = {}
    triangle_sets: dict[str, IntArray] = {}
    for name, per_block in m.cell_sets.items():
        if name.startswith("gmsh:"):
            continue
        cells = [
            offsets[i] + np.asarray(idx, dtype=np.int64)
            for i, idx in enumerate(per_block)
            if i in offsets and len(idx)
        ]
        tris = [
            m.cells[i].data[np.asarray(idx, dtype=np.int64)]
            for i, idx in enumerate(per_block)
            if m.cells[i].type == "triangle" and len(idx)
        ]
        if cells:
            cell_sets[name] = np.concatenate(cells)
        if tris:
            triangle_sets[name] = np.concatenate(tris)
        if not cells and not tris:
            cell_sets[name] = np.empty(0, dtype=np.int64)
    point_sets = {k: np.asarray(v) for k, v in m.point_sets.items()}
    return from_arrays(
        np.asarray(m.points, dtype=float),
        np.concatenate(tets),
        str(path),
        cell_sets,
        triangle_sets,
        point_sets,
    )

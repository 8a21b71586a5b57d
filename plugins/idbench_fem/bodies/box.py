"""Box meshes of the beam: parse a mesh spec into a :class:`SolidMesh`.

A mesh spec is one of

- ``"NXxNYxNZ"``: element divisions along x, y, z of the structured beam
  (each hex split into 6 tetrahedra around one diagonal, scikit-fem's
  :meth:`skfem.MeshTet.init_tensor`);
- a bare integer ``"N"``: the structured beam with about N nodes, ny = nz and
  elements as near cubic as the section allows;
- anything else: a path to a tetrahedral mesh file that meshio reads. The body
  is its bounding box: the clamped face is x = min x, the loaded face x = max x,
  both found geometrically (:func:`clamped_face`, :func:`loaded_face`).
"""

from __future__ import annotations

import functools
import math
import os
import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from idbench_fem.bodies.mesh import SolidMesh, read_mesh
from idbench_fem.bodies.mesh import from_arrays as solid_mesh
from idbench_fem.bodies.regions import Region, region_facets, region_nodes

LENGTH = 0.2
"""Default beam length along x (m)."""

WIDTH = 0.03
"""Default beam width along y (m)."""

HEIGHT = 0.03
"""Default beam height along z (m)."""

_DIVISIONS = re.compile(r"^\s*(\d+)\s*[xX]\s*(\d+)\s*[xX]\s*(\d+)\s*$")
MAX_NODES_ENV = "IDBENCH_MAX_NODES"
DEFAULT_MAX_NODES = 300_000
"""Largest structured mesh built unless ``$IDBENCH_MAX_NODES`` says otherwise."""
_BYTES_PER_NODE = 5_000
"""Rough peak memory of a model per node (6 tets a node, 12x12 tangents each)."""


def max_nodes() -> int:
    """The largest structured mesh accepted: ``$IDBENCH_MAX_NODES`` or 300,000."""
    text = os.environ.get(MAX_NODES_ENV, "")
    try:
        return int(text) if text else DEFAULT_MAX_NODES
    except ValueError:
        raise ValueError(f"{MAX_NODES_ENV}={text!r}: need a whole number") from None




def divisions_for_nodes(
    n_nodes: int, length: float = LENGTH, width: float = WIDTH
) -> tuple[int, int, int]:
    """Element divisions (nx, ny, ny) of the structured beam with about ``n_nodes``.

    Scans the section divisions ny, takes the nx that best matches the node
    count, and keeps the candidate that minimises
    ``|log(nodes / n_nodes)| + |log(hx / hy)|`` (node count and element shape).
    """
    if n_nodes < 8:
        raise ValueError(f"mesh spec {n_nodes!r}: a node-count target must be >= 8")
    best: tuple[float, tuple[int, int, int]] | None = None
    for ny in range(1, int(math.sqrt(n_nodes)) + 1):
        nx = max(1, round(n_nodes / (ny + 1) ** 2 - 1))
        nodes = (nx + 1) * (ny + 1) ** 2
        score = abs(math.log(nodes / n_nodes)) + abs(
            math.log((length / nx) / (width / ny))
        )
        if best is None or score < best[0]:
            best = (score, (nx, ny, ny))
    assert best is not None
    return best[1]


def structured(
    nx: int,
    ny: int,
    nz: int,
    size: tuple[float, float, float] = (LENGTH, WIDTH, HEIGHT),
    spec: str | None = None,
) -> SolidMesh:
    """Build the structured beam with ``nx x ny x nz`` hexes, each split into 6 tets.

    Built once per process and shared (its arrays are read-only): a sweep
    builds several models on each mesh (one per scenario and role).
    """
    for name, n in (("nx", nx), ("ny", ny), ("nz", nz)):
        if n < 1:
            raise ValueError(f"mesh divisions: {name} = {n}, must be >= 1")
    nodes = (nx + 1) * (ny + 1) * (nz + 1)
    if nodes > max_nodes():
        raise ValueError(
            f"mesh {nx}x{ny}x{nz}: {nodes:,} nodes, more than the limit of "
            f"{max_nodes():,} (about {nodes * _BYTES_PER_NODE / 2**30:.1f} GiB to "
            f"assemble; set {MAX_NODES_ENV} to raise it)"
        )
    return _structured(nx, ny, nz, tuple(size), spec or f"{nx}x{ny}x{nz}")


@functools.lru_cache(maxsize=8)
def _structured(
    nx: int, ny: int, nz: int, size: tuple[float, ...], spec: str
) -> SolidMesh:
    from skfem import MeshTet

    m = MeshTet.init_tensor(
        np.linspace(0.0, size[0], nx + 1),
        np.linspace(0.0, size[1], ny + 1),
        np.linspace(0.0, size[2], nz + 1),
    )
    mesh = from_arrays(m.p.T, m.t.T, spec)
    for value in vars(mesh).values():
        for a in value.values() if isinstance(value, dict) else [value]:
            if isinstance(a, np.ndarray):
                a.setflags(write=False)
    return mesh


def _tolerance(mesh: SolidMesh) -> float:
    return 1e-9 * float(np.max(mesh.upper - mesh.lower))


def clamped_face(mesh: SolidMesh) -> Region:
    """The selector of the beam's clamped face x = min x (to 1e-9 of the size)."""
    x0 = float(mesh.lower[0]) + _tolerance(mesh)
    return Region(half_space=((x0, 0.0, 0.0), (-1.0, 0.0, 0.0)))


def loaded_face(mesh: SolidMesh) -> Region:
    """The selector of the beam's loaded face x = max x (to 1e-9 of the size)."""
    x1 = float(mesh.upper[0]) - _tolerance(mesh)
    return Region(half_space=((x1, 0.0, 0.0), (1.0, 0.0, 0.0)))


def from_arrays(
    points: NDArray[np.float64], tets: NDArray[np.int64], spec: str
) -> SolidMesh:
    """Build the :class:`SolidMesh` of a beam from coordinates (N, 3) and tets (T, 4).

    Orients every tet positively and checks that the beam has flat end faces
    normal to x (:func:`clamped_face`, :func:`loaded_face`).

    Raises
    ------
    ValueError
        Bad arrays, degenerate or inverted tets, no end faces (one line).
    """
    mesh = solid_mesh(points, tets, spec)
    clamped = _nodes_or_none(mesh, clamped_face(mesh))
    on_start = np.zeros(len(mesh.points), dtype=bool)
    on_start[clamped] = True
    flat_start = on_start[mesh.tets].sum(axis=1) >= 3  # a tet with a face on x0
    loaded = _facets_or_none(mesh, loaded_face(mesh))
    if len(clamped) < 3 or not np.any(flat_start) or len(loaded) == 0:
        which = "loaded face x = max x" if len(loaded) == 0 else ""
        if len(clamped) < 3 or not np.any(flat_start):
            which = "clamped face x = min x"
        lo, hi = mesh.lower[0], mesh.upper[0]
        raise ValueError(
            f"mesh {spec!r}: has no {which} (x = {lo:g} .. {hi:g}); "
            "the beam must have flat end faces normal to x"
        )
    return mesh


def _nodes_or_none(mesh: SolidMesh, region: Region) -> NDArray[np.int64]:
    try:
        return region_nodes(mesh, region)
    except ValueError:
        return np.empty(0, dtype=np.int64)


def _facets_or_none(mesh: SolidMesh, region: Region) -> NDArray[np.int64]:
    try:
        return region_facets(mesh, region)
    except ValueError:
        return np.empty(0, dtype=np.int64)


def read_file(path: str | Path, spec: str | None = None) -> SolidMesh:
    """Read a tetrahedral beam mesh file (:func:`~idbench_fem.bodies.mesh.read_mesh`).

    Raises
    ------
    ValueError
        Unreadable file, no or not only linear tets, no end faces (one line).
    """
    mesh = read_mesh(path)
    return from_arrays(mesh.points, mesh.tets, spec or str(path))


def parse(spec: str) -> SolidMesh:
    """Build the beam mesh named by ``spec`` (see the module docstring).

    Raises
    ------
    ValueError
        Naming the bad spec and what is allowed.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(
            f"mesh spec {spec!r}: expected 'NXxNYxNZ' (e.g. '20x4x4'), a node "
            "count (e.g. '500') or a path to a tetrahedral mesh file"
        )
    s = spec.strip()
    if (m := _DIVISIONS.match(s)) is not None:
        nx, ny, nz = (int(g) for g in m.groups())
        if min(nx, ny, nz) < 1:
            raise ValueError(f"mesh spec {spec!r}: divisions must be >= 1")
        return structured(nx, ny, nz, spec=s)
    if s.isdigit():
        n = int(s)
        if not 8 <= n <= max_nodes():
            raise ValueError(
                f"mesh spec {spec!r}: a node count must be between 8 and "
                f"{max_nodes():,} (set {MAX_NODES_ENV} to raise the limit)"
            )
        return structured(*divisions_for_nodes(n), spec=s)
    path = Path(s).expanduser()
    if not path.is_file():
        raise ValueError(
            f"mesh spec {spec!r} is neither 'NXxNYxNZ' divisions (e.g. '20x4x4'), "
            "a node count (e.g. '500'), nor an existing mesh file"
        )
    return read_file(path, spec=s)

r"""Linear tetrahedral meshes of a closed surface, at asked node counts (gmsh).

:func:`mesh_surface` gives gmsh the surface's own triangles as a discrete
surface, reclassifies them (``gmsh.model.mesh.classifySurfaces``: patches
split at sharp edges, forReparametrization, so that gmsh can remesh them)
and builds a geometry on them (``createGeometry``), closes it into a volume
and meshes it (Frontal-Delaunay surfaces, Delaunay volume, optimised, one
thread) with a maximum element size h. The node count falls as h grows
(about as h^-3), so h is found by bisection on log h until the mesh has the
asked node count within :data:`NODE_TOLERANCE`: each trial a fresh gmsh
session, so that a node count gives the same mesh whatever else is asked.

The written file (gmsh MSH 4.1) has the physical groups ``surface`` (every
boundary triangle) and ``volume`` (every tet): select regions in the body
TOML by box, sphere, half-space or patch, or name ``surface``.

gmsh refusing the remeshed surface ("PLC Error: A segment and a facet
intersect", where the body is thinner than the element size) is a
:class:`ValueError` naming the size and what to do.

Quality: :func:`idbench_fem.bodies.mesh.tet_quality`, the mean ratio (1 for
a regular tet, 0 for a flat one); inverted elements are those whose signed
volume is not of the mesh's orientation (or zero).
"""

from __future__ import annotations

import contextlib
import io
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from idbench_fem.bodies.mesh import tet_quality
from idbench_fem.bodies.surface_file import Surface

NODE_TOLERANCE = 0.10
"""A mesh's node count is accepted within this fraction of the asked one."""

MAX_TRIES = 24
CLASSIFY_ANGLE = 40.0
"""Degrees: a dihedral angle sharper than this splits the surface's patches."""


@dataclass(frozen=True)
class SurfaceMesh:
    """One mesh :func:`mesh_surface` wrote, and what it is like.

    Attributes
    ----------
    path
        The file.
    asked, nodes, tets
        The asked node count, and the mesh's nodes and tetrahedra.
    h
        gmsh's maximum element size (m).
    tries
        Meshes made to find ``h``.
    inverted
        Tetrahedra with a volume <= 0 (0 for a usable mesh).
    min_quality
        The smallest mean-ratio quality of a tet (1 regular, 0 flat).
    volume
        The mesh's volume (m^3).
    seconds
        Wall time of the whole search.
    """

    path: Path
    asked: int
    nodes: int
    tets: int
    h: float
    tries: int
    inverted: int
    min_quality: float
    volume: float
    seconds: float


class MeshingError(ValueError):
    """gmsh could not mesh the surface at some size (one line, what to do)."""


def _mesh(surface: Surface, h: float, path: Path | None = None):  # type: ignore[no-untyped-def]
    """Mesh ``surface`` at maximum size ``h``: (points (N, 3), tets (T, 4)).

    Writes the mesh to ``path`` if given.

    Raises
    ------
    MeshingError
        gmsh fails (its last error message included).
    """
    import gmsh

    log = io.StringIO()
    gmsh.initialize(interruptible=False)
    try:
        opt = gmsh.option.setNumber
        opt("General.Terminal", 0)
        for name in ("General.NumThreads", "Mesh.MaxNumThreads1D",
                     "Mesh.MaxNumThreads2D", "Mesh.MaxNumThreads3D"):  # fmt: skip
            opt(name, 1)
        gmsh.logger.start()
        gmsh.model.add("surface")
        tag = gmsh.model.addDiscreteEntity(2)
        n = len(surface.points)
        gmsh.model.mesh.addNodes(2, tag, np.arange(1, n + 1), surface.points.ravel())
        gmsh.model.mesh.addElementsByType(tag, 2, [], (surface.triangles + 1).ravel())
        gmsh.model.mesh.classifySurfaces(
            math.radians(CLASSIFY_ANGLE), True, True, math.pi
        )
        gmsh.model.mesh.createGeometry()
        faces = [t for _, t in gmsh.model.getEntities(2)]
        loop = gmsh.model.geo.addSurfaceLoop(faces)
        volume = gmsh.model.geo.addVolume([loop])
        gmsh.model.geo.synchronize()
        gmsh.model.addPhysicalGroup(2, faces, name="surface")
        gmsh.model.addPhysicalGroup(3, [volume], name="volume")
        for name, value in (
            ("Mesh.Algorithm", 6), ("Mesh.Algorithm3D", 1), ("Mesh.RandomSeed", 1),
            ("Mesh.MeshSizeMin", 0.0), ("Mesh.MeshSizeMax", h),
            ("Mesh.MeshSizeFromCurvature", 0), ("Mesh.MeshSizeFromPoints", 0),
            ("Mesh.MeshSizeExtendFromBoundary", 0), ("Mesh.Optimize", 1),
            ("Mesh.MshFileVersion", 4.1), ("Mesh.Binary", 0), ("Mesh.SaveAll", 0),
        ):  # fmt: skip
            opt(name, value)
        with contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
            gmsh.model.mesh.generate(3)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        _, nodes = gmsh.model.mesh.getElementsByType(4)
        if len(nodes) == 0:
            raise MeshingError("gmsh made no tetrahedra")
        index = np.zeros(int(tags.max()) + 1, dtype=np.int64)
        index[tags.astype(np.int64)] = np.arange(len(tags))
        points = coords.reshape(-1, 3)
        tets = index[nodes.astype(np.int64)].reshape(-1, 4)
        if path is not None:
            gmsh.write(str(path))
        return points, tets
    except MeshingError:
        raise
    except Exception as exc:
        errors = [m for m in gmsh.logger.get() if "rror" in m] or [str(exc)]
        raise MeshingError(" ".join(errors[-1].split())) from None
    finally:
        gmsh.logger.stop()
        gmsh.finalize()


def _count(points, tets) -> int:  # type: ignore[no-untyped-def]
    """Nodes the tets use."""
    return len(np.unique(tets))


def first_size(surface: Surface, n_nodes: int) -> float:
    """A first guess of h for ``n_nodes`` (a tet mesh has about V / h^3 nodes)."""
    return float((surface.volume / n_nodes) ** (1.0 / 3.0))


def mesh_surface(
    surface: Surface,
    n_nodes: int,
    path: Path,
    on_try: Callable[[float, int], None] | None = None,
) -> SurfaceMesh:
    """Mesh ``surface`` with ``n_nodes`` nodes (within 10%) into ``path``.

    Bisection on log h: a bracket [h_fine, h_coarse] of sizes giving too many
    and too few nodes is found by doubling or halving from
    :func:`first_size`, then narrowed by its geometric mean (secant on log
    nodes against log h when both ends are known). ``on_try(h, nodes)`` is
    called after each trial mesh. The closest mesh found is written if none
    is within the tolerance (after :data:`MAX_TRIES`).

    Raises
    ------
    MeshingError
        gmsh fails at a size (naming it and what to do).
    """
    t0 = time.perf_counter()
    tried: dict[float, int] = {}

    def trial(h: float) -> int:
        try:
            points, tets = _mesh(surface, h)
        except MeshingError as exc:
            raise MeshingError(
                f"surface {surface.path!r}: gmsh cannot mesh it at h = {h:.3g} m "
                f"(for {n_nodes} nodes): {exc}; if it says that a segment and a "
                "facet intersect, the remeshed surface crosses itself where the "
                "body is thinner than h: ask for more nodes"
            ) from None
        tried[h] = _count(points, tets)
        if on_try is not None:
            on_try(h, tried[h])
        return tried[h]

    def good(n: int) -> bool:
        return abs(n / n_nodes - 1) <= NODE_TOLERANCE

    h = first_size(surface, n_nodes)
    fine: tuple[float, int] | None = None  # too many nodes
    coarse: tuple[float, int] | None = None  # too few
    for _ in range(MAX_TRIES):
        n = trial(h)
        if good(n):
            break
        if n > n_nodes:
            fine = (h, n)
        else:
            coarse = (h, n)
        if fine is None:
            h /= 2.0
        elif coarse is None:
            h *= 2.0
        else:
            (h1, n1), (h2, n2) = fine, coarse
            slope = math.log(n2 / n1) / math.log(h2 / h1) if n1 != n2 else -3.0
            guess = h1 * (n_nodes / n1) ** (1.0 / min(slope, -0.5))
            middle = math.sqrt(h1 * h2)
            inside = min(h1, h2) < guess < max(h1, h2)
            h = guess if inside and len(tried) % 2 else middle
    best = min(tried, key=lambda x: abs(math.log(tried[x] / n_nodes)))
    points, tets = _mesh(surface, best, path)
    x = points[tets]
    det = np.einsum(
        "ti,ti->t", x[:, 1] - x[:, 0], np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 0])
    )
    sign = 1.0 if det.sum() >= 0 else -1.0  # gmsh's orientation, whichever
    return SurfaceMesh(
        path=path, asked=n_nodes, nodes=_count(points, tets), tets=len(tets),
        h=best, tries=len(tried), inverted=int((sign * det <= 0).sum()),
        min_quality=float(tet_quality(points, tets).min()),
        volume=float(np.abs(det).sum() / 6.0), seconds=time.perf_counter() - t0,
    )  # fmt: skip

"""Regions of a body: a mesh's named sets or geometric selectors, resolved.

A :class:`Region` names a set of the mesh or selects by geometry (box, sphere,
half-space, surface patch, slab along x); :func:`region_nodes`,
:func:`region_facets` and :func:`region_cells` turn it into node, boundary
facet or tet indices of a :class:`~idbench_fem.bodies.mesh.SolidMesh`, with
one-line errors for unknown names and empty regions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from idbench_fem.bodies.mesh import SolidMesh
from idbench_fem.bodies.surface import project_to_surface

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Vec = tuple[float, float, float]


@dataclass(frozen=True)
class Region:
    """A named mesh region or a geometric selector; exactly one field is set.

    Attributes
    ----------
    name
        A gmsh physical group, meshio cell set or point set.
    box
        (lower, upper) corners: nodes with lower <= x <= upper.
    sphere
        (centre, radius): nodes within radius of centre.
    half_space
        (point, normal): nodes with (x - point) . normal >= 0.
    patch
        (point, radius): the surface around the surface point nearest to
        ``point``: boundary facets whose centroid lies within radius of it,
        and always the facet containing it.
    slab
        (index, count): slab ``index`` (0-based) of ``count`` equal slabs
        along x of the mesh's bounding box: points x with
        ``min(floor(count (x - x_min) / (x_max - x_min)), count - 1) == index``
        (a point on a slab boundary belongs to the slab after it).
    excluding
        Not a selector: what the region leaves out (a slab around an
        inclusion, say); cells, facets and nodes that it selects are removed.
    """

    name: str | None = None
    box: tuple[Vec, Vec] | None = None
    sphere: tuple[Vec, float] | None = None
    half_space: tuple[Vec, Vec] | None = None
    patch: tuple[Vec, float] | None = None
    slab: tuple[int, int] | None = None
    excluding: Region | None = None

    def __post_init__(self) -> None:
        given = [k for k in SELECTORS if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(
                f"region: give exactly one of {', '.join(SELECTORS)} (got {given})"
            )
        if self.slab is not None and not 0 <= self.slab[0] < self.slab[1]:
            raise ValueError(f"region slab {self.slab!r}: need 0 <= index < count")

    @property
    def kind(self) -> str:
        """Which selector this is."""
        return next(k for k in SELECTORS if getattr(self, k) is not None)

    def describe(self) -> str:
        """Short text for messages, e.g. ``'ligament'`` or ``sphere (...)``."""
        text = (
            repr(self.name)
            if self.name is not None
            else f"{self.kind} {getattr(self, self.kind)!r}"
        )
        if self.excluding is not None:
            text += f" excluding {self.excluding.describe()}"
        return text


SELECTORS = ("name", "box", "sphere", "half_space", "patch", "slab")


def _unknown(mesh: SolidMesh, name: str, what: str) -> ValueError:
    return ValueError(
        f"{what} {name!r} is not in mesh {mesh.label}; its regions are "
        f"{', '.join(mesh.names) or '(none)'}"
    )


def _selected(x: FloatArray, region: Region, mesh: SolidMesh) -> NDArray[np.bool_]:
    """Which of the points ``x`` (n, 3) a box, sphere, half-space or slab selects."""
    if region.slab is not None:
        index, count = region.slab
        x0, x1 = float(mesh.lower[0]), float(mesh.upper[0])
        t = (x[:, 0] - x0) / (x1 - x0)
        return np.asarray(np.minimum((t * count).astype(np.int64), count - 1) == index)
    if region.box is not None:
        lo, hi = (np.asarray(v, dtype=float) for v in region.box)
        return np.all((x >= lo) & (x <= hi), axis=1)
    if region.sphere is not None:
        centre, radius = region.sphere
        return np.linalg.norm(x - np.asarray(centre), axis=1) <= radius
    assert region.half_space is not None
    point, normal = (np.asarray(v, dtype=float) for v in region.half_space)
    return (x - point) @ normal >= 0.0


def patch_facets(
    mesh: SolidMesh, point: Vec, radius: float, what: str = "patch"
) -> IntArray:
    """Boundary facets around the surface point nearest to ``point``.

    Facets whose centroid lies within ``radius`` of that surface point, and
    the facet containing it (so the patch is never empty on a coarse mesh).

    Raises
    ------
    ValueError
        If ``point`` is farther than ``radius`` from the surface.
    """
    q, facet, _, dist = project_to_surface(mesh, np.asarray(point, dtype=float))
    if dist[0] > radius:
        raise ValueError(
            f"{what} at {list(point)} is {dist[0]:.3g} m from the surface of "
            f"{mesh.label}, more than its radius {radius:g} m: move it onto the "
            "surface"
        )
    centroids = mesh.points[mesh.facets].mean(axis=1)
    near = np.linalg.norm(centroids - q[0], axis=1) <= radius
    near[facet[0]] = True
    return np.flatnonzero(near)


def region_facets(mesh: SolidMesh, region: Region, what: str = "region") -> IntArray:
    """Boundary facets of a region (selectors: facets whose 3 nodes it selects).

    Raises
    ------
    ValueError
        Unknown name, or no boundary facet in the region.
    """
    return _members(mesh, region, what, "facets")


def region_nodes(mesh: SolidMesh, region: Region, what: str = "region") -> IntArray:
    """Nodes of a region (a patch gives the nodes of its facets).

    Raises
    ------
    ValueError
        Unknown name, or no node in the region.
    """
    return _members(mesh, region, what, "nodes")


def region_cells(mesh: SolidMesh, region: Region, what: str = "region") -> IntArray:
    """Tets of a region: a volume set by name, or tets whose centroid it selects.

    Raises
    ------
    ValueError
        Unknown or non-volume name, patch selectors, or no tet in the region.
    """
    return _members(mesh, region, what, "cells")


_NOUNS = {"facets": "boundary facet", "nodes": "node", "cells": "tetrahedron"}
"""What :func:`_members` finds of each kind, for its error message."""


def _members(mesh: SolidMesh, region: Region, what: str, kind: str) -> IntArray:
    """The facets, nodes or cells (``kind``) of a region, less its ``excluding``.

    By name (the mesh's set of that kind), by patch (its facets, or their
    nodes; not cells) or by selector (the nodes it selects, the facets whose 3
    nodes it selects, the tets whose centroid it selects).
    """
    sets = {
        "facets": mesh.facet_sets,
        "nodes": mesh.node_sets,
        "cells": mesh.cell_sets,
    }[kind]
    if kind == "cells" and region.patch is not None:
        raise ValueError(f"{what}: a patch selects surface, not cells")
    if kind == "cells" and region.name in mesh.node_sets.keys() - sets:
        raise ValueError(
            f"{what} {region.name!r} is not a volume region of mesh "
            f"{mesh.label}; volume regions: {', '.join(sorted(sets))}"
        )
    if region.name is not None:
        if region.name not in sets:
            raise _unknown(mesh, region.name, what)
        out = sets[region.name]
    elif region.patch is not None:
        out = patch_facets(mesh, *region.patch, what=what)
        if kind == "nodes":
            out = np.unique(mesh.facets[out])
    elif kind == "cells":
        out = np.flatnonzero(
            _selected(mesh.points[mesh.tets].mean(axis=1), region, mesh)
        )
    else:
        chosen = _selected(mesh.points, region, mesh)
        if kind == "facets":
            chosen = chosen[mesh.facets].all(axis=1)
        out = np.flatnonzero(chosen)
    if region.excluding is not None:
        out = np.setdiff1d(out, _members(mesh, region.excluding, what, kind))
    if len(out) == 0:
        raise ValueError(
            f"{what} {region.describe()} contains no {_NOUNS[kind]} of mesh "
            f"{mesh.label}"
        )
    return out

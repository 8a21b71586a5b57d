"""A body description resolved on a mesh: fixed nodes, markers, points, moduli.

Each function takes a parsed :class:`idbench_fem.bodies.description.Body` and a
:class:`idbench_fem.bodies.mesh.SolidMesh` and raises a one-line
``ValueError`` naming the body file, the region and the mesh when the
description does not fit the mesh (unknown or empty region, markers off the
body, regions that do not partition it, ...). :func:`check` runs them all.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from idbench_fem.bodies.mesh import SolidMesh, read_mesh
from idbench_fem.bodies.regions import (
    Region,
    region_cells,
    region_facets,
    region_nodes,
)
from idbench_fem.bodies.surface import inside, project_to_surface

if TYPE_CHECKING:
    from idbench_fem.bodies.description import Body

SNAP_DISTANCE = 0.005
"""The default ``[markers] snap_distance`` (m)."""

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def fixed_nodes(body: Body, mesh: SolidMesh) -> IntArray:
    """Indices of the fixed nodes (all components zero); none without ``[fixed]``.

    Raises
    ------
    ValueError
        Unknown or empty region, or one that cannot stop rigid motion (fewer
        than three nodes not on one line).
    """
    if body.fixed is None:  # held by its supports (springs) only
        return np.zeros(0, dtype=np.int64)
    nodes = region_nodes(mesh, body.fixed, what=f"{body.source}: [fixed] region")
    x = mesh.points[nodes] - mesh.points[nodes].mean(axis=0)
    sv = np.linalg.svd(x, compute_uv=False) if len(x) >= 2 else np.zeros(1)
    scale = float(np.max(np.ptp(mesh.points, axis=0)))
    if len(nodes) < 3 or sv[1] <= 1e-9 * scale:
        raise ValueError(
            f"{body.source}: [fixed] region {body.fixed.describe()} has "
            f"{len(nodes)} node(s) on one line in {mesh.label}: the body could "
            "still rotate; fix a larger region"
        )
    return nodes


def driven_nodes(body: Body, name: str, mesh: SolidMesh) -> IntArray:
    """The nodes manipulation ``name`` (a displacement-controlled grasp) moves.

    Raises
    ------
    ValueError
        A patch off the surface, or one sharing nodes with the fixed region
        (a node cannot be held still and moved).
    """
    from idbench_fem.bodies.loads import driven_nodes as patch_nodes

    m = body.manipulation(name)
    nodes = patch_nodes(m, mesh)
    both = np.intersect1d(nodes, fixed_nodes(body, mesh))
    if len(both):
        raise ValueError(
            f"{body.source}: [[manipulation]] {m.name!r}: its patch shares "
            f"{len(both)} node(s) with the [fixed] region in {mesh.label}; move "
            "the grasp point or shrink its radius"
        )
    return nodes


def marker_points(body: Body, mesh: SolidMesh) -> FloatArray:
    """Marker coordinates (M, 3) on the surface of ``mesh``.

    Coordinates are projected to the nearest surface point (with
    ``placement = "volume"``: kept as given, if inside the body); a region
    gives all of its surface nodes.

    Raises
    ------
    ValueError
        A marker farther than ``snap_distance`` from the surface (naming it
        and whether it is outside or inside), or a region with no surface node.
    """
    mk = body.markers
    if mk.region is not None:
        nodes = region_nodes(mesh, mk.region, what=f"{body.source}: [markers] region")
        on_surface = np.intersect1d(nodes, mesh.surface_nodes)
        if len(on_surface) == 0:
            raise ValueError(
                f"{body.source}: [markers] region {mk.region.describe()} has no "
                f"surface node in {mesh.label}"
            )
        return mesh.points[on_surface]
    pts = np.asarray(mk.points, dtype=float)
    if mk.placement == "volume":
        out = np.flatnonzero(~inside(mesh, pts))
        if len(out):
            i = int(out[0])
            raise ValueError(
                f"{body.source}: [markers] point {i + 1} at {list(mk.points[i])} "
                f"lies outside {mesh.label} (placement = 'volume')"
                + _more(len(out))
            )
        return pts
    snapped, _, _, dist = project_to_surface(mesh, pts)
    far = np.flatnonzero(dist > mk.snap_distance)
    if len(far):
        i = int(far[0])
        side = "inside" if inside(mesh, pts[i])[0] else "outside"
        default = " (the default)" if mk.snap_distance == SNAP_DISTANCE else ""
        raise ValueError(
            f"{body.source}: [markers] point {i + 1} at {list(mk.points[i])} is "
            f"{side} the body of mesh {mesh.label}, {dist[i]:.3g} m from its "
            "surface, farther than "
            f"snap_distance = {mk.snap_distance:g} m{default}"
            + _more(len(far))
            + "; move it onto the surface or raise snap_distance"
        )
    return snapped


def _more(n: int) -> str:
    """`` (and k more)`` for ``n`` > 1 culprits of which the first is named."""
    return f" (and {n - 1} more)" if n > 1 else ""


def target_depths(body: Body, mesh: SolidMesh) -> FloatArray:
    """Each target's distance (T,) to the surface of ``mesh``: < 0 outside it (m).

    Raises
    ------
    ValueError
        A target outside the mesh (numbered from 1 as the TOML lists them).
    """
    if not body.targets:
        return np.zeros(0)
    pts = np.array([p for _, p in body.targets], dtype=float)
    dist = project_to_surface(mesh, pts)[3]
    out = ~inside(mesh, pts)
    if out.any():
        i = int(np.flatnonzero(out)[0])
        name, point = body.targets[i]
        raise ValueError(
            f"{body.source}: [targets] {name} (target {i + 1}) at {list(point)} "
            f"lies outside {mesh.label}, {dist[i]:.3g} m from its surface"
            + _more(int(out.sum()))
            + "; a hidden target must lie inside the body"
        )
    return dist


def shape_error_points(
    body: Body, truth: SolidMesh, margin: float | None = None
) -> FloatArray:
    """Shape-error points (P, 3): a grid clipped to the body, or its nodes.

    The grid spans the bounding box of ``truth`` (cell centres, x slowest)
    and keeps the points inside it and at least ``margin`` (default
    ``body.shape_error.margin``) from its surface, so they can also be
    located in coarser meshes of the same body. With ``nodes = true``, the
    truth mesh's nodes that far inside.
    """
    from idbench_fem.fem.interpolation import grid_points

    se = body.shape_error
    margin = se.margin if margin is None else margin
    if se.nodes:
        pts = truth.points
        keep = np.ones(len(pts), dtype=bool)
    else:
        lo, hi = truth.points.min(axis=0), truth.points.max(axis=0)
        pts = grid_points(se.grid, lo, hi)
        keep = inside(truth, pts)
    if margin > 0:
        idx = np.flatnonzero(keep)
        keep[idx] = project_to_surface(truth, pts[idx])[3] >= margin
    if not keep.any():
        raise ValueError(
            f"{body.source}: [shape_error] no point lies {margin:g} m inside "
            f"{truth.label}; use a finer grid or a smaller margin"
        )
    return pts[keep]


def target_points(body: Body, mesh: SolidMesh) -> FloatArray:
    """The body's hidden targets (T, 3), each inside ``mesh`` (the reference).

    Raises
    ------
    ValueError
        A target outside the body: its number (from 1, in the order of
        ``[targets]``), name, distance from the surface and the mesh.
    """
    pts = np.array([point for _, point in body.targets], dtype=float).reshape(-1, 3)
    out = np.flatnonzero(~inside(mesh, pts)) if len(pts) else []
    if len(out):
        i = int(out[0])
        dist = float(project_to_surface(mesh, pts[i : i + 1])[3][0])
        raise ValueError(
            f"{body.source}: target {i + 1} ({body.targets[i][0]!r}) at "
            f"{pts[i].tolist()} lies outside the body, {dist:.3g} m from the "
            f"surface of {mesh.path!r}; a hidden target must be inside it"
        )
    return pts


def element_regions(body: Body, mesh: SolidMesh) -> IntArray:
    """Parameter region of every tet (T,): zeros for one E.

    Raises
    ------
    ValueError
        A region with no tet, a tet in none of them or in two.
    """
    region = np.zeros(len(mesh.tets), dtype=np.int64)
    if not body.parameter_regions:
        return region
    count = np.zeros(len(mesh.tets), dtype=np.int64)
    for r, reg in enumerate(body.parameter_regions):
        cells = region_cells(mesh, reg, what=f"{body.source}: [parameters] region")
        region[cells] = r
        count[cells] += 1
    if (count != 1).any():
        t = int(np.flatnonzero(count != 1)[0])
        how = "no" if count[t] == 0 else "more than one"
        raise ValueError(
            f"{body.source}: [parameters] regions: tetrahedron {t} of {mesh.label} "
            f"is in {how} region ({int((count == 0).sum())} in none, "
            f"{int((count > 1).sum())} in several); regions must partition the body"
        )
    return region


def element_moduli(body: Body, mesh: SolidMesh) -> FloatArray:
    """Young's modulus of every tet (T,): E, overridden by ``E_regions``.

    Raises
    ------
    ValueError
        If a region of ``E_regions`` is not a volume region of ``mesh``.
    """
    E = np.full(len(mesh.tets), body.material.E)
    for name, value in body.material.E_regions:
        what = f"{body.source}: [material] E_regions"
        E[region_cells(mesh, Region(name=name), what=what)] = value
    return E


def mesh_paths(body: Body) -> list[Path]:
    """Model meshes then the truth; generate them first if missing and possible."""
    paths = [*body.mesh.models, body.mesh.truth]
    missing = [p for p in paths if not p.is_file()]
    if missing and body.mesh.geometry is not None:
        from idbench_fem.bodies.geometry import make_meshes

        make_meshes(body.mesh.geometry, list(body.mesh.sizes), missing[0].parent)
        missing = [p for p in paths if not p.is_file()]
    if missing:
        raise ValueError(
            f"{body.source}: mesh file {str(missing[0])!r} does not exist"
            + ("" if body.mesh.geometry else " (add [mesh] generate = {...})")
        )
    return paths


def check(body: Body, meshes: list[SolidMesh] | None = None) -> None:
    """Resolve every region of ``body`` on each mesh (default: all its files).

    Raises the first one-line ``ValueError`` met.
    """
    from idbench_fem.bodies.loads import nodal_forces

    if meshes is None:
        meshes = [read_mesh(p) for p in mesh_paths(body)]
    for mesh in meshes:
        fixed_nodes(body, mesh)
        marker_points(body, mesh)
        element_regions(body, mesh)
        element_moduli(body, mesh)
        for s in body.supports:  # springs: a surface region each
            region_facets(mesh, s.region, what=f"{body.source}: [[support]] region")
        for m in body.manipulations:
            nodal_forces(m, mesh, body.material.density)
            if m.driven:
                driven_nodes(body, m.name, mesh)
    shape_error_points(body, meshes[-1])
    target_points(body, meshes[-1])

"""Where a body's observed and scored points sit in a model mesh.

:func:`place_points` places the body's markers, shape-error grid, probes and
targets on the reference mesh and gives the P1 interpolation matrices that
read their displacements off a state of a model mesh (:class:`PlacedPoints`):
markers projected onto its surface (or located in its volume), grid points in
the tet containing them or the nearest one, clipped.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from idbench_fem.bodies import resolve
from idbench_fem.bodies.description import Body
from idbench_fem.bodies.mesh import SolidMesh
from idbench_fem.bodies.surface import project_to_surface
from idbench_fem.fem.interpolation import (
    OutsideMesh,
    barycentric,
    interpolation_matrix,
    weights_matrix,
)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True, eq=False)
class PlacedPoints:
    """A body's observed and scored points in a model mesh.

    Attributes
    ----------
    marker_points, grid_points, target_points
        The markers (M, 3), shape-error points (G, 3) and targets (T, 3).
    markers, grid, targets
        Their P1 interpolation matrices on the state, (3M, n), (3G, n),
        (3T, n).
    probes
        Probe name -> its interpolation matrix (3, n).
    """

    marker_points: FloatArray
    grid_points: FloatArray
    target_points: FloatArray
    markers: sp.csr_matrix
    grid: sp.csr_matrix
    targets: sp.csr_matrix
    probes: dict[str, sp.csr_matrix]


def place_points(
    body: Body,
    mesh: SolidMesh,
    reference: SolidMesh,
    markers: int,
    f2f: IntArray,
) -> PlacedPoints:
    """Place ``markers`` of the body's markers, its grid, probes and targets.

    Markers and shape-error points are placed on ``reference`` (the
    comparison's truth mesh), then located in ``mesh``: markers on its
    surface (or in its tets with ``placement = "volume"``), shape-error
    points in the tet containing them (``locate = "contained"``) or the
    nearest one, clipped; ``f2f`` maps full dofs to the state's.

    Raises
    ------
    ValueError
        If the body has fewer than ``markers`` markers on ``reference``, or
        a target outside it (targets are located in ``mesh`` like the grid:
        a coarse mesh that misses one takes its nearest tet's weights).
    """
    pts = reference_markers(body, reference)
    if markers > len(pts):
        raise ValueError(
            f"{body.source}: {markers} markers asked for, the body has "
            f"{len(pts)} on {reference.label}"
        )
    chosen = farthest_points(pts, markers)
    marker_points = pts[chosen]
    grid_points = reference_grid(body, reference)

    def located(points: FloatArray, what: Callable[[int], str]) -> sp.csr_matrix:
        try:
            return interpolation_matrix(points, mesh.points, mesh.tets, f2f)
        except OutsideMesh as exc:
            raise ValueError(
                f"{body.source}: {what(exc.index)} at "
                f"{np.round(points[exc.index], 9).tolist()} lies outside mesh "
                f"{mesh.label}"
            ) from None

    if body.markers.placement == "volume" and body.markers.region is None:
        observe = located(
            marker_points,
            lambda i: f"[markers] point {chosen[i] + 1} (placement = 'volume')",
        )
    else:
        observe = surface_interpolation(mesh, marker_points, f2f)
    if body.shape_error.locate == "contained":
        grid = located(
            grid_points, lambda i: f"[shape_error] point {i + 1} (locate = 'contained')"
        )
    else:
        grid = nearest_interpolation(mesh, grid_points, f2f)
    probes = {}
    for name, point in body.probes:
        probes[name] = located(
            np.asarray(point, dtype=float)[None, :],
            functools.partial("[[probe]] {0!r}".format, name),
        )
    target_points = reference_targets(body, reference)  # inside the body
    targets = nearest_interpolation(mesh, target_points, f2f)
    return PlacedPoints(
        marker_points, grid_points, target_points, observe, grid, targets, probes
    )


@functools.lru_cache(maxsize=8)
def reference_markers(body: Body, reference: SolidMesh) -> FloatArray:
    """The body's markers placed on the reference mesh (cached), (M, 3)."""
    return resolve.marker_points(body, reference)


@functools.lru_cache(maxsize=8)
def reference_targets(body: Body, reference: SolidMesh) -> FloatArray:
    """The body's hidden targets, checked inside the reference mesh (cached), (T, 3)."""
    return resolve.target_points(body, reference)


@functools.lru_cache(maxsize=8)
def reference_grid(body: Body, reference: SolidMesh) -> FloatArray:
    """The body's shape-error points in the reference mesh (cached), (G, 3)."""
    return resolve.shape_error_points(body, reference)


def farthest_points(points: FloatArray, m: int) -> IntArray:
    """Indices of ``m`` of ``points``: the first m of a farthest-point ordering.

    Starts from point 0, so for listed markers the first is kept; when m
    equals the number of points, all of them in their order.
    """
    if m >= len(points):
        return np.arange(len(points))
    chosen = [0]
    dist = np.linalg.norm(points - points[0], axis=1)
    for _ in range(m - 1):  # m markers, not mesh entities
        i = int(dist.argmax())
        chosen.append(i)
        dist = np.minimum(dist, np.linalg.norm(points - points[i], axis=1))
    return np.asarray(chosen)


def surface_interpolation(
    mesh: SolidMesh, points: FloatArray, full_to_free: IntArray
) -> sp.csr_matrix:
    """Interpolate at the nearest surface points of ``mesh`` to ``points``."""
    _, facet, bary, _ = project_to_surface(mesh, points)
    return weights_matrix(mesh.facets[facet], bary, full_to_free)


def nearest_interpolation(
    mesh: SolidMesh, points: FloatArray, full_to_free: IntArray, k: int = 16
) -> sp.csr_matrix:
    """P1 interpolation at ``points``; outside points use the nearest tet, clipped.

    Among the ``k`` tets with the nearest centroids, the one whose smallest
    barycentric coordinate is largest; its negative coordinates are set to
    zero and the rest rescaled to sum to one.
    """
    x = mesh.points[mesh.tets]
    k = min(k, len(mesh.tets))
    _, cand = cKDTree(x.mean(axis=1)).query(points, k=k)
    cand = np.asarray(cand).reshape(len(points), k)
    bary = barycentric(points[:, None, :], x[cand])  # (P, k, 4)
    best = bary.min(axis=2).argmax(axis=1)
    rows = np.arange(len(points))
    w = np.clip(bary[rows, best], 0.0, None)
    w /= w.sum(axis=1, keepdims=True)
    return weights_matrix(mesh.tets[cand[rows, best]], w, full_to_free)

"""A coarse partition of a body into parameter cells, shared by all its meshes.

The cells are the Voronoi cells of centres found once, on the reference
(truth) mesh, by k-means (:func:`scipy.cluster.vq.kmeans2`, seeded, started
from random sample points) of points
drawn uniformly by volume inside it: cells of about equal volume whatever the
mesh grading. Every mesh of the body assigns each tetrahedron to the centre
nearest its centroid (:func:`assign`), so a cell is the same part of the body
on the truth and on every model mesh, and the truth's and the models'
parameters name the same cells. Each cell's geometry (centroid, volume,
neighbours and shared areas) is measured on the reference mesh
(:func:`cell_geometry`): that is what the smoothness prior and the
localization use.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.cluster.vq import kmeans2
from scipy.spatial import cKDTree

from idbench_fem.bodies.mesh import SolidMesh

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

log = logging.getLogger(__name__)

SAMPLES_PER_CELL = 200
"""Points drawn per cell for the k-means (at least :data:`MIN_SAMPLES`)."""
MIN_SAMPLES = 20_000
ITERATIONS = 30

_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def tet_volumes(points: FloatArray, tets: IntArray) -> FloatArray:
    """Volume of each tetrahedron (T,)."""
    x = points[tets]
    return np.abs(np.linalg.det(x[:, 1:] - x[:, :1])) / 6.0


def tet_centroids(points: FloatArray, tets: IntArray) -> FloatArray:
    """Centroid of each tetrahedron (T, 3)."""
    return np.asarray(points[tets].mean(axis=1))


def sample_points(mesh: SolidMesh, n: int, rng: np.random.Generator) -> FloatArray:
    """``n`` points (n, 3) uniform by volume inside the mesh."""
    vol = tet_volumes(mesh.points, mesh.tets)
    tet = rng.choice(len(vol), size=n, p=vol / vol.sum())
    w = -np.log(rng.random((n, 4)))  # Dirichlet(1, 1, 1, 1): uniform in a tet
    w /= w.sum(axis=1, keepdims=True)
    return np.einsum("ij,ijk->ik", w, mesh.points[mesh.tets[tet]])


def kmeans_centres(mesh: SolidMesh, cells: int, seed: int = 0) -> FloatArray:
    """Centres (p, 3) of ``cells`` k-means cells of the mesh's volume.

    Centres whose Voronoi cell holds no tetrahedron centroid of ``mesh`` are
    dropped (logged), so p <= cells.

    Raises
    ------
    ValueError
        If ``cells`` < 1 or more than the mesh has tetrahedra.
    """
    if not 1 <= cells <= len(mesh.tets):
        raise ValueError(
            f"field cells = {cells}: need 1 .. {len(mesh.tets)} (the tetrahedra of "
            f"{mesh.path!r})"
        )
    return _centres(mesh, int(cells), int(seed))


@functools.lru_cache(maxsize=16)
def _centres(mesh: SolidMesh, cells: int, seed: int) -> FloatArray:
    rng = np.random.default_rng(seed)
    x = sample_points(mesh, max(MIN_SAMPLES, SAMPLES_PER_CELL * cells), rng)
    if cells == 1:
        return np.asarray(x.mean(axis=0, keepdims=True))
    start = x[rng.choice(len(x), size=cells, replace=False)]
    centres, _ = kmeans2(x, start, iter=ITERATIONS, minit="matrix", seed=rng)
    used = np.unique(assign(mesh, centres))
    if len(used) < cells:
        log.warning(
            "field: %d of %d k-means cells hold no tetrahedron of %s; dropped",
            cells - len(used), cells, mesh.path,
        )  # fmt: skip
    centres = centres[used]
    centres.setflags(write=False)
    return np.asarray(centres)


def assign(mesh: SolidMesh, centres: FloatArray) -> IntArray:
    """The cell (nearest centre) of each tetrahedron's centroid, (T,)."""
    _, cell = cKDTree(centres).query(tet_centroids(mesh.points, mesh.tets))
    return np.asarray(cell, dtype=np.int64)


@dataclass(frozen=True, eq=False)
class CellGeometry:
    """The cells as measured on one mesh.

    Attributes
    ----------
    centroids
        (p, 3) volume-weighted centroids.
    volumes
        (p,) volumes.
    edges
        (e, 2) pairs i < j of cells sharing a face.
    areas
        (e,) the area they share.
    """

    centroids: FloatArray
    volumes: FloatArray
    edges: IntArray
    areas: FloatArray


def cell_geometry(mesh: SolidMesh, cell: IntArray, p: int) -> CellGeometry:
    """Centroids, volumes, neighbours and shared areas of cells ``cell`` (T,).

    Raises
    ------
    ValueError
        If a cell holds no tetrahedron of ``mesh``.
    """
    vol = tet_volumes(mesh.points, mesh.tets)
    volumes = np.bincount(cell, weights=vol, minlength=p)
    if np.any(volumes <= 0):
        empty = int(np.flatnonzero(volumes <= 0)[0])
        raise ValueError(f"field cell {empty} holds no tetrahedron of {mesh.path!r}")
    c = tet_centroids(mesh.points, mesh.tets) * vol[:, None]
    centroids = np.stack(
        [np.bincount(cell, weights=c[:, i], minlength=p) for i in range(3)], axis=1
    ) / volumes[:, None]
    faces = mesh.tets[:, _FACES].reshape(-1, 3)
    owner = np.repeat(np.arange(len(mesh.tets)), 4)
    key = np.sort(faces, axis=1)
    order = np.lexsort(key.T[::-1])
    key, owner, faces = key[order], owner[order], faces[order]
    same = np.all(key[1:] == key[:-1], axis=1)  # interior faces: adjacent rows
    a, b = cell[owner[:-1][same]], cell[owner[1:][same]]
    x = mesh.points[faces[:-1][same]]
    area = 0.5 * np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)
    cross = a != b
    i, j = np.minimum(a, b)[cross], np.maximum(a, b)[cross]
    pairs, inverse = np.unique(np.stack([i, j], axis=1), axis=0, return_inverse=True)
    areas = np.bincount(inverse.ravel(), weights=area[cross], minlength=len(pairs))
    return CellGeometry(centroids, volumes, pairs.astype(np.int64), areas)

r"""Consistent nodal forces of the manipulations on P1 tetrahedra.

Each manipulation is a dead load proportional to the load fraction t in [0, 1]
(step k of K: t = k / K); the arrays are the full nodal forces (N, 3) in N.

- traction (Pa) on surface facets: :math:`f_a = t\, \mathbf{t}\, A_f / 3`
  at each vertex a of each facet f (exact for a uniform traction);
- pressure (Pa), *dead* on the reference normal: :math:`f_a = -t\, p\,
  \mathbf{n}_f A_f / 3` (positive p pushes into the body; the normal does not
  follow the deformation, so the load stays linear in t and its work is
  conservative, at the price of being less accurate at large rotations);
- gravity: :math:`f_a = t\, \rho\, \mathbf{g}\, V_e / 4` for each vertex of
  each tet (exact for P1);
- grasp: a total force F spread uniformly over the patch area,
  :math:`f_a = t\, \mathbf{F} (A_f / 3) / A_{patch}`, i.e. a uniform
  traction F / A_patch on the boundary facets around the surface point
  nearest to ``point`` (:func:`~idbench_fem.bodies.regions.patch_facets`).

A displacement-controlled grasp (``displacement`` instead of ``force``) has
no external force: it prescribes the displacement of its patch's nodes
(:func:`driven_nodes`), and :func:`nodal_forces` gives zeros for it.

A traction or pressure needs a surface: a region name that is only a volume
group of the mesh is refused (its facet set is the volume's whole boundary,
the fixed face included).

The totals are exactly t times (traction x area), (-p x sum n A), (rho g V)
and F.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from idbench_fem.bodies.mesh import SolidMesh
from idbench_fem.bodies.regions import region_facets

if TYPE_CHECKING:
    from idbench_fem.bodies.manipulations import Manipulation

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def _scatter(mesh: SolidMesh, corners: IntArray, per_corner: FloatArray) -> FloatArray:
    """Add ``per_corner`` (K, 3) loads to the nodes ``corners`` (K,), (N, 3)."""
    f = np.zeros((len(mesh.points), 3))
    np.add.at(f, corners, per_corner)
    return f


def traction_forces(
    mesh: SolidMesh, facets: IntArray, traction: FloatArray
) -> FloatArray:
    """Nodal forces (N, 3) of a uniform traction vector (3,) on ``facets``."""
    area = mesh.facet_areas(facets)
    load = np.repeat(area / 3.0, 3)[:, None] * np.asarray(traction, dtype=float)
    return _scatter(mesh, mesh.facets[facets].ravel(), load)


def traction_weights(mesh: SolidMesh, facets: IntArray) -> FloatArray:
    """Nodal weights (N,) of a uniform traction on ``facets``: area / 3 per vertex.

    The force of a traction vector t is ``weights[:, None] * t``. Each node's
    sum runs over its facets in the order of their sorted node triples, so
    the weights do not depend on how a mesh numbers its facets.
    """
    tri = np.sort(mesh.facets[facets], axis=1)
    facets = np.asarray(facets)[np.lexsort(tri.T[::-1])]
    w = np.zeros(len(mesh.points))
    np.add.at(
        w, mesh.facets[facets].ravel(), np.repeat(mesh.facet_areas(facets) / 3.0, 3)
    )
    return w


def pressure_forces(mesh: SolidMesh, facets: IntArray, pressure: float) -> FloatArray:
    """Nodal forces (N, 3) of a dead pressure (positive: into the body)."""
    n2a = mesh.facet_normals(facets)  # outward normal times twice the area
    load = np.repeat(-pressure * n2a / 6.0, 3, axis=0)
    return _scatter(mesh, mesh.facets[facets].ravel(), load)


def gravity_forces(
    mesh: SolidMesh, density: float, acceleration: FloatArray
) -> FloatArray:
    """Nodal forces (N, 3) of the body force rho g: rho g V / 4 per tet vertex."""
    weight = np.repeat(density * mesh.volumes / 4.0, 4)[:, None]
    return _scatter(mesh, mesh.tets.ravel(), weight * np.asarray(acceleration))


def patch_forces(mesh: SolidMesh, facets: IntArray, force: FloatArray) -> FloatArray:
    """Nodal forces (N, 3) of a total ``force`` (3,) spread over ``facets`` by area."""
    area = mesh.facet_areas(facets)
    return traction_forces(mesh, facets, np.asarray(force, dtype=float) / area.sum())


def nodal_forces(
    manipulation: Manipulation, mesh: SolidMesh, density: float, t: float = 1.0
) -> FloatArray:
    """Full nodal external forces (N, 3) of ``manipulation`` at load fraction t.

    Parameters
    ----------
    manipulation
        A parsed :class:`idbench_fem.bodies.description.Manipulation`.
    mesh
        The body's mesh (model or truth).
    density
        Mass density (kg/m3), used by gravity.
    t
        Load fraction, k / K at step k of K.

    Raises
    ------
    ValueError
        If the manipulation's region is unknown, empty or (grasp) off the
        surface.
    """
    m = manipulation
    what = f"manipulation {m.name!r}"
    if m.kind == "gravity":
        if density <= 0:
            raise ValueError(f"{what}: gravity needs a material density > 0")
        return t * gravity_forces(mesh, density, np.asarray(m.vector))
    assert m.region is not None
    name = m.region.name
    surface_load = m.kind in ("traction", "pressure")
    if surface_load and name is not None and mesh.volume_only(name):
        raise ValueError(
            f"{what}: region {name!r} is a volume region of mesh {mesh.label}: a "
            f"{m.kind} loads a surface, and this one would load the volume's whole "
            "boundary (the fixed face too); name a surface group or select the "
            "surface with box, sphere, half_space or patch"
        )
    facets = region_facets(mesh, m.region, what=f"{what}: region")
    if m.kind == "traction":
        return t * traction_forces(mesh, facets, np.asarray(m.vector))
    if m.kind == "pressure":
        return t * pressure_forces(mesh, facets, float(m.pressure or 0.0))
    if m.kind == "grasp" and m.driven:
        return np.zeros((len(mesh.points), 3))
    if m.kind == "grasp":
        return t * patch_forces(mesh, facets, np.asarray(m.vector))
    raise ValueError(f"{what}: unknown kind {m.kind!r}")


def driven_nodes(manipulation: Manipulation, mesh: SolidMesh) -> IntArray:
    """The nodes a displacement-controlled grasp moves (its patch's), sorted.

    Raises
    ------
    ValueError
        If the manipulation is not displacement-controlled, or its patch is
        off the surface.
    """
    m = manipulation
    if not m.driven or m.region is None:
        raise ValueError(f"manipulation {m.name!r} prescribes no displacement")
    facets = region_facets(mesh, m.region, what=f"manipulation {m.name!r}: region")
    return np.unique(mesh.facets[facets].ravel()).astype(np.int64)

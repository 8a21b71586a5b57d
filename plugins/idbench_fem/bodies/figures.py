r"""A manipulation's load measured on a mesh, and conserved across meshes.

The same manipulation puts a different load on each mesh of a curved body: a
pressure inside a sphere acts on the facets whose three nodes the sphere
holds, and a coarse polyhedron holds less area and less volume than a fine
one. :func:`figures` measures what a mesh carries (the names and units of
:data:`idbench.LOAD_FIGURES`), at the end of the load path, from all its
nodal loads (those on fixed nodes too: what the tool or gravity applies,
whatever share the support takes):

- ``resultant`` :math:`|\sum_a f_a|` (N);
- ``moment`` :math:`|\sum_a (x_a - c) \times f_a|` (N m) about the centroid
  c of the fixed region (its boundary facets' area-weighted centroid, the
  mean of its nodes if it has no boundary facet); a moment that is small
  against the resultant times the body's size (a push towards the support)
  makes a large ratio of small numbers;
- ``area``: the loaded boundary facets' area (m^2; 0 for gravity);
- ``fixed_area``: the boundary facets whose three nodes are fixed (m^2);
  ``moment`` and ``fixed_area`` are left out for a body without fixed nodes
  (held by springs alone);
- ``volume`` (m^3) and ``mass`` (density times volume, kg; for a conserved
  gravity load, the mass its weight stands for: times the factor below).

With ``conserve = "resultant"`` on a manipulation, :func:`conserve_scale`
is the factor that gives a mesh's nodal loads the resultant of the
*reference* mesh's (the comparison's truth, on which markers are placed):
:math:`s = |R_{ref}| / |R_{mesh}|`, so every mesh of a comparison carries
the same total force (for gravity: the organ's weight, so its mass),
distributed as its own selector captures it. The reference mesh itself
gets exactly 1.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from idbench_fem.bodies import resolve
from idbench_fem.bodies.loads import nodal_forces
from idbench_fem.bodies.mesh import SolidMesh
from idbench_fem.bodies.regions import region_facets

if TYPE_CHECKING:
    from idbench_fem.bodies.description import Body
    from idbench_fem.bodies.manipulations import Manipulation

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

CONSERVE = ("none", "resultant")
"""Values of a manipulation's ``conserve`` key."""


def fixed_region(mesh: SolidMesh, fixed: IntArray) -> tuple[float, FloatArray]:
    """The fixed region's boundary area (m^2) and centroid (3,).

    Its boundary facets are those whose three nodes are fixed; the centroid
    is their area-weighted centroid, or the fixed nodes' mean without any.
    """
    is_fixed = np.zeros(len(mesh.points), dtype=bool)
    is_fixed[fixed] = True
    facets = np.flatnonzero(is_fixed[mesh.facets].all(axis=1))
    area = mesh.facet_areas(facets)
    if area.sum() > 0:
        centres = mesh.points[mesh.facets[facets]].mean(axis=1)
        return float(area.sum()), np.asarray(area @ centres / area.sum())
    return 0.0, np.asarray(mesh.points[fixed].mean(axis=0))


def loaded_area(m: Manipulation, mesh: SolidMesh) -> float:
    """The area (m^2) of the boundary facets ``m`` loads (0 for gravity)."""
    if m.region is None:
        return 0.0
    facets = region_facets(mesh, m.region, what=f"manipulation {m.name!r}: region")
    return float(mesh.facet_areas(facets).sum())


def figures(
    body: Body,
    m: Manipulation,
    mesh: SolidMesh,
    forces: FloatArray,
    fixed: IntArray | None = None,
    scale: float = 1.0,
) -> dict[str, float]:
    """The load figures of ``forces`` (N, 3), ``m``'s end load on ``mesh``.

    ``fixed``: the body's fixed nodes on ``mesh`` (None: resolved here);
    ``scale``: the factor ``forces`` carry (:func:`conserve_scale`), by which
    the mass a gravity load stands for is scaled too. See the module
    docstring for what each figure is.
    """
    fixed = resolve.fixed_nodes(body, mesh) if fixed is None else fixed
    f = np.asarray(forces, dtype=float)
    volume = float(mesh.volumes.sum())
    out = {
        "resultant": float(np.linalg.norm(f.sum(axis=0))),
        "area": loaded_area(m, mesh),
        "volume": volume,
        "mass": float(body.material.density) * volume * (
            scale if m.kind == "gravity" else 1.0
        ),
    }
    if len(fixed):  # a body held by springs alone has no clamp to take moments at
        fixed_area, centre = fixed_region(mesh, fixed)
        moment = np.cross(mesh.points - centre, f).sum(axis=0)
        out |= {"moment": float(np.linalg.norm(moment)), "fixed_area": fixed_area}
    return out


def resultant(body: Body, m: Manipulation, mesh: SolidMesh) -> FloatArray:
    """The resultant (3,) of ``m``'s end load on ``mesh`` (N)."""
    f = nodal_forces(m, mesh, body.material.density)
    return np.asarray(f.sum(axis=0))


def conserve_scale(
    body: Body, m: Manipulation, mesh: SolidMesh, reference: SolidMesh
) -> float:
    """The factor on ``m``'s nodal loads on ``mesh`` (1.0 unless conserved).

    With ``conserve = "resultant"``: |R_reference| / |R_mesh|; exactly 1.0
    on the reference mesh itself.

    Raises
    ------
    ValueError
        A resultant that is (nearly) zero on either mesh (a pressure all
        around a closed surface, say): there is no total force to conserve.
    """
    if m.conserve == "none" or mesh is reference or m.driven:
        return 1.0
    own, ref = (np.linalg.norm(resultant(body, m, x)) for x in (mesh, reference))
    f = nodal_forces(m, mesh, body.material.density)
    size = float(np.abs(f).sum())
    if not own > 1e-9 * size or not ref > 0:
        on = mesh.label if not own > 1e-9 * size else reference.label
        raise ValueError(
            f"{body.source}: [[manipulation]] {m.name!r} conserve = "
            f"{m.conserve!r}: its resultant on {on} is zero (the load balances "
            "itself), so there is no total force to conserve; remove conserve"
        )
    return float(ref / own)

r"""What a solid model's parameters are: E, E per region, or E per field cell.

Each tetrahedron e belongs to one parameter r(e) and has a factor c_e, so
that its modulus is :math:`E_e = \theta_{r(e)} c_e` and the internal force is
linear in theta (:mod:`idbench_fem.models.solid`).

- One E, or E per ``[parameters]`` region: c_e is the element's true modulus
  over its parameter's true value (1 except where ``E_regions`` makes part of
  a region stiffer than the parameter it belongs to).
- A field (``[field]`` or the ``field_cells`` option,
  :mod:`idbench_fem.bodies.field`): r(e) is the element's cell
  (:mod:`idbench_fem.bodies.partition`, the same cells on every mesh), named
  ``E_cell000``, ...; the true value of a cell is the volume-weighted
  geometric mean of the truth's moduli over it, measured on the reference
  (truth) mesh. On the reference mesh c_e keeps the truth's moduli inside
  each cell (the truth at the true values is the truth field exactly); on a
  model mesh c_e = 1: a model knows nothing finer than its cells.
  ``cells = "known"``: two parameters, ``E_background`` and ``E_inclusion``,
  the truth's inclusion known exactly (no neighbours: independent in a
  smoothness prior).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from idbench import ParameterField, ParameterSpec
from idbench_fem.bodies import resolve
from idbench_fem.bodies.description import Body
from idbench_fem.bodies.field import FieldSpec, inclusion_mask, truth_factors
from idbench_fem.bodies.mesh import SolidMesh
from idbench_fem.bodies.partition import (
    assign,
    cell_geometry,
    kmeans_centres,
    tet_centroids,
    tet_volumes,
)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

BOUNDS = (1e-3, 1e3)
"""Parameter bounds as multiples of the body's E."""


@dataclass(frozen=True, eq=False)
class Parameterisation:
    """A mesh's parameters: each element's parameter and factor, the spec, the field.

    Attributes
    ----------
    regions
        (T,) each element's parameter.
    factors
        (T,) c_e: the element's modulus over its parameter's value.
    spec
        Names, bounds and true values.
    field
        The cells, for a field (else None).
    describe
        What of it keys the truth (empty without a field).
    """

    regions: IntArray
    factors: FloatArray
    spec: ParameterSpec
    field: ParameterField | None = None
    describe: dict[str, Any] | None = None


def field_spec(body: Body, settings: Any) -> FieldSpec | None:
    """The body's ``[field]`` with the model options on top (None: no field)."""
    spec = body.modulus_field
    cells = getattr(settings, "field_cells", None)
    if spec is None and cells is None:
        return None
    spec = spec or FieldSpec()
    changes = {
        name: getattr(settings, f"field_{name}")
        for name in ("cells", "length", "std", "seed")
        if getattr(settings, f"field_{name}", None) is not None
    }
    return replace(spec, **changes)


def parameterise(
    body: Body, mesh: SolidMesh, reference: SolidMesh, settings: Any = None
) -> Parameterisation:
    """The parameters of ``body`` on ``mesh`` (see the module docstring).

    Raises
    ------
    ValueError
        One line: regions that do not partition the body, an empty
        inclusion, too many cells for the reference mesh.
    """
    E = float(body.material.E)
    lo, hi = body.parameter_bounds or (BOUNDS[0] * E, BOUNDS[1] * E)
    spec = field_spec(body, settings)
    if spec is None:
        regions = resolve.element_regions(body, mesh)
        moduli = resolve.element_moduli(body, mesh)
        names = body.parameter_names
        true = np.array(body.parameter_values)
        params = ParameterSpec(
            names, tuple(lo for _ in names), tuple(hi for _ in names),
            default=tuple(float(v) for v in true),
        )  # fmt: skip
        return Parameterisation(regions, moduli / true[regions], params)
    return _field(body, spec, mesh, reference, (lo, hi))


def _field(
    body: Body, spec: FieldSpec, mesh: SolidMesh, reference: SolidMesh,
    bounds: tuple[float, float],
) -> Parameterisation:  # fmt: skip
    """The field's parameterisation of ``mesh`` (cells found on ``reference``)."""
    if spec.known:
        centres = None
        ref_cells = inclusion_mask(spec, reference, body.source).astype(np.int64)
        cells = inclusion_mask(spec, mesh, body.source, True).astype(np.int64)
        names: tuple[str, ...] = ("E_background", "E_inclusion")
    else:
        assert isinstance(spec.cells, int)
        centres = kmeans_centres(reference, spec.cells, spec.seed)
        ref_cells, cells = assign(reference, centres), assign(mesh, centres)
        names = tuple(f"E_cell{i:03d}" for i in range(len(centres)))
    p = len(names)
    geometry = cell_geometry(reference, ref_cells, p)
    ref_moduli = resolve.element_moduli(body, reference) * truth_factors(
        spec, reference, body.source
    )
    vol = tet_volumes(reference.points, reference.tets)
    log_mean = np.bincount(ref_cells, weights=vol * np.log(ref_moduli), minlength=p)
    true = np.exp(log_mean / geometry.volumes)
    inside, centre = None, None
    if spec.inclusions:
        mask = inclusion_mask(spec, reference, body.source)
        inside = np.bincount(ref_cells, weights=vol * mask, minlength=p)
        inside = inside / geometry.volumes
        x = tet_centroids(reference.points, reference.tets)
        centre = (x[mask] * vol[mask, None]).sum(axis=0) / vol[mask].sum()
    edges, areas = geometry.edges, geometry.areas
    if spec.known:  # two regions told apart: independent in the prior
        edges, areas = edges[:0], areas[:0]
    field = ParameterField(
        geometry.centroids, geometry.volumes, edges, areas, spec.length, spec.std,
        inside, centre,
    )  # fmt: skip
    if _same_mesh(mesh, reference):
        moduli = resolve.element_moduli(body, mesh) * truth_factors(
            spec, mesh, body.source
        )
        factors = moduli / true[cells]
    else:
        factors = np.ones(len(mesh.tets))
    lo, hi = bounds
    params = ParameterSpec(
        names, (lo,) * p, (hi,) * p, default=tuple(float(v) for v in true)
    )
    describe = {
        "field": {
            "cells": spec.cells, "p": p, "seed": spec.seed, "length": spec.length,
            "std": spec.std,
            "inclusions": [[r.describe(), c] for r, c in spec.inclusions],
            "random": None if spec.random is None else repr(spec.random),
        }
    }  # fmt: skip
    return Parameterisation(cells, factors, params, field, describe)


def _same_mesh(a: SolidMesh, b: SolidMesh) -> bool:
    """Whether two meshes are the same file (or the same object)."""
    if a is b:
        return True
    pa, pb = Path(a.path), Path(b.path)
    if pa.is_file() and pb.is_file():
        return pa.resolve() == pb.resolve()
    return False

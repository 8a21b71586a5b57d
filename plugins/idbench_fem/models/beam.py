"""The St Venant-Kirchhoff cantilever beam: a body of the solid model, in memory.

``svk-beam`` is :class:`~idbench_fem.models.solid.SolidModel` on the body
:func:`beam_body` builds for a box mesh (:mod:`idbench_fem.bodies.box`): the
face x = min x clamped, a dead uniform traction (the scenario's
:class:`~idbench_fem.models.beam_settings.EndTraction`) on x = max x, P1 SVK,
markers on the end face and the top edges, the shape-error grid of the box,
the tip (the end-face centre) as the probe ``tip``, and one E or slabs along
x plus an inclusion box as the parameter regions. Its settings are
:class:`~idbench_fem.models.beam_settings.BeamSettings`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from idbench import ModelSpec, Scenario
from idbench_fem.bodies import box
from idbench_fem.bodies.description import (
    Body,
    Manipulation,
    Markers,
    Material,
    MeshFiles,
    ShapeError,
)
from idbench_fem.bodies.design import Design
from idbench_fem.bodies.mesh import SolidMesh
from idbench_fem.bodies.regions import Region
from idbench_fem.fem.interpolation import marker_points
from idbench_fem.models.beam_scenarios import DESIGN_MODULI, DESIGN_TRACTIONS
from idbench_fem.models.beam_settings import DEFAULT_E, BeamSettings, EndTraction
from idbench_fem.models.solid import SolidModel
from idbench_fem.models.solid_settings import SolidSettings

E_BOUNDS = (1.0, 1e8)
"""Bounds (Pa) of every Young's modulus of the beam."""

BODY = "svk-beam"
"""The beam body's ``source`` (it has no file)."""


def beam_body(
    mesh: SolidMesh,
    scenario: Scenario | EndTraction,
    markers: int = 2,
    settings: BeamSettings | None = None,
) -> Body:
    """The cantilever as a body of the solid model, built in memory on ``mesh``.

    Clamped at x = min x (:func:`~idbench_fem.bodies.box.clamped_face`),
    loaded by the scenario's uniform end traction on x = max x, ``markers``
    markers on the end face and the top edges
    (:func:`~idbench_fem.fem.interpolation.marker_points`, located in each
    mesh's tets), the regular ``settings.grid`` of the bounding box (located
    exactly), the tip (the end-face centre) as the probe ``tip``, and
    ``settings.parameters``: one E, or ``regions`` slabs along x (default 2,
    or 1 with an inclusion) and the ``inclusion`` box as the last region.

    Raises
    ------
    ValueError
        A scenario that is not an end traction, a bad inclusion box.
    """
    s = settings or BeamSettings()
    load = EndTraction.of(scenario)
    lower, upper = mesh.lower, mesh.upper
    centre = 0.5 * (lower + upper)
    centre[0] = upper[0]
    target = 0.5 * (lower + upper)  # a hidden target: on the axis, 90% along
    target[0] = lower[0] + 0.9 * (upper[0] - lower[0])
    traction = _vec([load.magnitude * d for d in load.direction])
    return Body(
        source=BODY,
        mesh=MeshFiles(Path(mesh.path)),
        material=Material("svk", DEFAULT_E, s.nu, 0.0),
        fixed=box.clamped_face(mesh),
        manipulations=(
            Manipulation(load.name, "traction", box.loaded_face(mesh), traction),
        ),
        markers=Markers(
            tuple(_vec(p) for p in marker_points(int(markers), lower, upper)),
            placement="volume",
        ),
        shape_error=ShapeError(s.grid, locate="contained"),
        parameter_regions=_parameter_regions(s),
        parameter_bounds=E_BOUNDS,
        probes=(("tip", _vec(centre)),),
        targets=(("target", _vec(target)),),
        design=beam_design(mesh, _parameter_regions(s)),
    )


def beam_design(mesh: SolidMesh, regions: tuple[Region, ...] = ()) -> Design:
    """The beam's offline design: its 14 end tractions (``DESIGN_TRACTIONS``)."""
    own = tuple(
        Manipulation(name, "traction", box.loaded_face(mesh), t)
        for name, t in DESIGN_TRACTIONS.items()
    )
    names = [f"E_{r.name}" if r.name is not None else f"E_region{i}"
             for i, r in enumerate(regions)] or ["E"]  # fmt: skip
    lo, hi = DESIGN_MODULI
    return Design(tuple(DESIGN_TRACTIONS), own, tuple((n, lo, hi) for n in names))


def _vec(p: Any) -> tuple[float, float, float]:
    return (float(p[0]), float(p[1]), float(p[2]))


def _parameter_regions(s: BeamSettings) -> tuple[Region, ...]:
    """Slabs along x (``regions``) and the ``inclusion`` box, for ``E_regions``."""
    if s.parameters == "E":
        return ()
    inclusion = None
    if s.inclusion is not None:
        corners = np.asarray(s.inclusion, dtype=float)
        if corners.shape != (6,) or np.any(corners[1::2] <= corners[0::2]):
            raise ValueError(
                f"inclusion {s.inclusion!r}: need (x0, x1, y0, y1, z0, z1), x0 < x1 "
                "etc."
            )
        inclusion = Region(box=(_vec(corners[0::2]), _vec(corners[1::2])))
    slabs = s.regions if s.regions is not None else (2 if inclusion is None else 1)
    out = [Region(slab=(r, slabs), excluding=inclusion) for r in range(slabs)]
    return (*out, inclusion) if inclusion is not None else tuple(out)


def solid_settings(s: BeamSettings, chord_ratio: float | None = None) -> SolidSettings:
    """The solid model's settings for the beam's (its absolute ``atol`` aside).

    Plain Newton from the given state at every step (``path_reuse=False``), as
    the study's beam has always been solved: its numbers stay the study's.
    """
    return SolidSettings(
        body=BODY, law="svk", nu=s.nu, rtol=s.rtol, max_iterations=s.max_iterations,
        solver=s.solver, processes=s.processes, chord_ratio=chord_ratio,
        sensitivity_refine=s.sensitivity_refine, path_reuse=False,
    )  # fmt: skip


def build(
    mesh: SolidMesh,
    scenario: Scenario | EndTraction,
    n_steps: int = 20,
    markers: int = 2,
    settings: BeamSettings | None = None,
    chord_ratio: float | None = None,
) -> SolidModel:
    """The beam on ``mesh`` as a :class:`SolidModel`, true values as defaults.

    ``chord_ratio``: see :class:`~idbench_fem.models.solid_settings.SolidSettings`.
    """
    s = settings or BeamSettings()
    limit = len(mesh.surface_nodes)  # one marker a surface node at most
    if markers > limit:
        raise ValueError(
            f"{markers} markers asked for on mesh {mesh.path!r}: at most {limit} "
            "(its surface nodes)"
        )
    body = beam_body(mesh, scenario, markers, s)
    model = SolidModel(
        body, mesh, body.manipulations[0].name, mesh, n_steps, markers,
        solid_settings(s, chord_ratio), absolute_atol=s.atol,
    )  # fmt: skip
    model.parameters = replace(
        model.parameters, default=s.true_values(model.parameters.p)
    )
    model.max_markers = limit
    return model


def make_model(spec: ModelSpec) -> SolidModel:
    """Build the beam of ``spec`` (registered as ``"svk-beam"``).

    ``spec.mesh`` is a box mesh spec (:func:`idbench_fem.bodies.box.parse`);
    ``spec.settings`` a :class:`BeamSettings`, a mapping of its fields, or
    None (the defaults).
    """
    settings = spec.settings
    if settings is None:
        settings = BeamSettings()
    elif isinstance(settings, Mapping):
        settings = BeamSettings(**settings)
    if str(spec.mesh).startswith("rom:"):  # a reduced model of a box mesh
        from idbench_fem.models.reduced import ReducedModel, design_check
        from idbench_fem.models.reduction import parse_spec, reduce

        rspec = parse_spec(spec.mesh)
        fine = build(box.parse(rspec.mesh), spec.scenario, spec.n_steps,
                     spec.markers, settings)  # fmt: skip
        red = reduce(fine.body, rspec, solid_settings(settings), design_check,
                     fine.mesh_data)  # fmt: skip
        return ReducedModel(fine, red, rspec)  # type: ignore[return-value]
    return build(
        box.parse(spec.mesh), spec.scenario, spec.n_steps, spec.markers, settings
    )

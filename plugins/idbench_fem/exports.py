"""The flat namespace of :mod:`idbench_fem`: which module gives each public name.

``from idbench_fem import SolidModel`` imports :mod:`idbench_fem.models.solid`
then, not when the plugin loads (loading it for ``idbench --help`` stays cheap).
"""

from __future__ import annotations

import importlib
import sys
from typing import Any

EXPORTS = {
    "models.solid": "SolidModel",
    "models.solid_settings": "SolidSettings",
    "models.beam": "beam_body",
    "models.beam_settings": "BeamSettings EndTraction end_traction",
    "bodies.description": "Body load_body parse_body",
    "bodies.catalog": "SHIPPED body_path get_body get_mesh",
    "bodies.mesh": "Region SolidMesh read_mesh",
    "bodies.loads": "nodal_forces",
    "bodies.geometry": "make_meshes",
    "fem.materials": "LAWS NeoHookean Svk make_material",
    "fem.svk_assembly": "Assembler",
    "fem.law_assembly": "LawAssembler",
    "fem.newton": "NewtonSolve",
    "fem.batched": "BatchedSteps",
    "fem.solver": "BACKENDS SolverError make_solver",
    "tools.calibrate": "Calibration CalibrationSettings calibrate",
}
"""Module (below idbench_fem) -> the public names it gives the package."""

HOME = {n: f"idbench_fem.{m}" for m, names in EXPORTS.items() for n in names.split()}
"""Public name -> the module that defines it."""


def load(name: str) -> Any:
    """The object ``name`` of :mod:`idbench_fem`, imported (and kept) at first use.

    Raises
    ------
    AttributeError
        If ``name`` is not one of :data:`HOME`.
    """
    if name not in HOME:
        raise AttributeError(f"module 'idbench_fem' has no attribute {name!r}")
    value = getattr(importlib.import_module(HOME[name]), name)
    setattr(sys.modules["idbench_fem"], name, value)
    return value

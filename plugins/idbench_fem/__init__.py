"""Built-in FE model plugin: the St Venant-Kirchhoff beam and general solid bodies.

Its folders, each importing only the ones below it (an import-linter contract):

- :mod:`idbench_fem.tools`: ``idbench calibrate`` (the beam's effective-E map);
- :mod:`idbench_fem.models`: the forward models (the solid, the beam), their
  settings and scenarios;
- :mod:`idbench_fem.bodies`: meshes (the general one, the structured box), the
  body description, the shipped bodies, region selectors, loads, gmsh geometry;
- :mod:`idbench_fem.fem`: kernels, assembly per law, materials, Newton, linear
  solvers, batched steps, step-worker processes, interpolation.

The names in ``__all__`` are importable from here (``from idbench_fem import
SolidModel``); each is imported at first use, so loading the plugin stays cheap.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import idbench
from idbench_fem.models.beam_scenarios import SCENARIOS


@idbench.hookimpl
def register_scenarios(register: Callable[[Any], None]) -> None:
    """Register the beam's load paths (bend-y, bend-z, stretch-x, mixed-30/60)."""
    for scenario in SCENARIOS:
        register(scenario)
    from idbench_fem.models.solid_settings import all_scenarios

    for scenario in all_scenarios({s.name for s in SCENARIOS}):
        register(scenario)


@idbench.hookimpl
def register_models(register: Callable[..., None]) -> None:
    """Register the cantilever as ``"svk-beam"`` and body TOMLs as ``"solid"``."""
    from idbench_fem.models.beam import make_model
    from idbench_fem.models.beam_settings import BeamSettings
    from idbench_fem.models.solid import make_model as make_solid
    from idbench_fem.models.solid_settings import SolidSettings

    register("svk-beam", make_model, settings=BeamSettings, defaults=BEAM_DEFAULTS)
    register("solid", make_solid, settings=SolidSettings, defaults=SOLID_DEFAULTS)


@idbench.hookimpl
def register_commands(register: Callable[[str, Any], None]) -> None:
    """Register ``idbench calibrate`` (the beam's effective-E map)."""
    from idbench_fem.tools.commands import CALIBRATE

    register("calibrate", CALIBRATE)


BEAM_DEFAULTS = idbench.ModelDefaults(
    truth_mesh="80x11x11",
    meshes=("9x2x2", "14x3x3", "20x4x4"),
    scenarios=("bend-y",),
    prior=(2500.0, 2500.0),
    quick={"truth_mesh": "40x5x5", "meshes": ("14x3x3", "20x4x4")},
    shorthands={
        "E-true": ("true.E", "true Young's modulus (Pa)"),
        "nu": ("nu", "Poisson ratio"),
    },
    primary=True,
)
"""The study's comparison (DESIGN.md section 7): what ``idbench compare`` runs."""


SOLID_DEFAULTS = idbench.ModelDefaults(
    truth_mesh="16000",
    meshes=("200", "500", "1000"),
    scenarios=("grasp-lift",),
    prior=(2000.0, 2000.0),
    quick={"truth_mesh": "1000", "meshes": ("200", "500")},
    shorthands={"body": ("body", "body TOML path or shipped name (liver, kidney)")},
)
"""The shipped liver (settings' default body): meshes by node count, grasp-lift."""


_EXPORTS = {
    "idbench_fem.models.solid": ("SolidModel",),
    "idbench_fem.models.solid_settings": ("SolidSettings",),
    "idbench_fem.models.beam": ("SvkBeam",),
    "idbench_fem.models.beam_settings": ("BeamSettings", "EndTraction", "end_traction"),
    "idbench_fem.bodies.description": ("Body", "load_body", "parse_body"),
    "idbench_fem.bodies.catalog": ("SHIPPED", "body_path", "get_body", "get_mesh"),
    "idbench_fem.bodies.mesh": ("Region", "SolidMesh", "read_mesh"),
    "idbench_fem.bodies.box": ("BeamMesh",),
    "idbench_fem.bodies.loads": ("nodal_forces",),
    "idbench_fem.bodies.geometry": ("make_meshes",),
    "idbench_fem.fem.materials": ("LAWS", "NeoHookean", "Svk", "make_material"),
    "idbench_fem.fem.svk_assembly": ("Assembler",),
    "idbench_fem.fem.law_assembly": ("LawAssembler",),
    "idbench_fem.fem.newton": ("NewtonSolve",),
    "idbench_fem.fem.batched": ("BatchedSteps",),
    "idbench_fem.fem.solver": ("BACKENDS", "SolverError", "make_solver"),
    "idbench_fem.tools.calibrate": ("Calibration", "CalibrationSettings", "calibrate"),
}
"""Module -> the public names it gives this package (imported at first use)."""

_HOME = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = ["BEAM_DEFAULTS", "SCENARIOS", "SOLID_DEFAULTS", *sorted(_HOME)]


def __getattr__(name: str) -> Any:
    """Import a re-exported name from its module at first use (PEP 562)."""
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(_HOME[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})

"""Built-in model plugin: the St Venant-Kirchhoff beam and general solid bodies.

Folders: ``tools`` -> ``models`` -> ``bodies`` -> ``fem`` (each imports only
those after it); the public names of ``__all__`` are re-exported here flat.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import idbench
from idbench_fem.bodies.catalog import SHIPPED, body_path, get_body, get_mesh
from idbench_fem.bodies.description import Body, load_body, parse_body
from idbench_fem.bodies.geometry import make_meshes
from idbench_fem.bodies.loads import nodal_forces
from idbench_fem.bodies.mesh import SolidMesh, read_mesh
from idbench_fem.bodies.regions import Region
from idbench_fem.fem.batched import BatchedSteps
from idbench_fem.fem.law_assembly import LawAssembler
from idbench_fem.fem.materials import LAWS, NeoHookean, Svk, make_material
from idbench_fem.fem.newton import NewtonSolve
from idbench_fem.fem.solver import BACKENDS, SolverError, make_solver
from idbench_fem.fem.svk_assembly import Assembler
from idbench_fem.models.beam import beam_body
from idbench_fem.models.beam import make_model as make_beam
from idbench_fem.models.beam_scenarios import SCENARIOS
from idbench_fem.models.beam_settings import BeamSettings, EndTraction, end_traction
from idbench_fem.models.solid import SolidModel
from idbench_fem.models.solid import make_model as make_solid
from idbench_fem.models.solid_settings import SolidSettings, all_scenarios
from idbench_fem.tools.calibrate import Calibration, CalibrationSettings, calibrate
from idbench_fem.tools.check import CHECK
from idbench_fem.tools.commands import CALIBRATE
from idbench_fem.tools.surface import MESH

__all__ = [
    "BACKENDS",
    "BEAM_DEFAULTS",
    "LAWS",
    "SCENARIOS",
    "SHIPPED",
    "SOLID_DEFAULTS",
    "Assembler",
    "BatchedSteps",
    "BeamSettings",
    "Body",
    "Calibration",
    "CalibrationSettings",
    "EndTraction",
    "LawAssembler",
    "NeoHookean",
    "NewtonSolve",
    "Region",
    "SolidMesh",
    "SolidModel",
    "SolidSettings",
    "SolverError",
    "Svk",
    "beam_body",
    "body_path",
    "calibrate",
    "end_traction",
    "get_body",
    "get_mesh",
    "load_body",
    "make_material",
    "make_meshes",
    "make_solver",
    "nodal_forces",
    "parse_body",
    "read_mesh",
]


@idbench.hookimpl
def register_scenarios(register: Callable[[Any], None]) -> None:
    """Register the beam's load paths (bend-y, bend-z, stretch-x, mixed-30/60)."""
    for scenario in SCENARIOS:
        register(scenario)
    for scenario in all_scenarios({s.name for s in SCENARIOS}):
        register(scenario)


@idbench.hookimpl
def register_models(register: Callable[..., None]) -> None:
    """Register the cantilever as ``"svk-beam"`` and body TOMLs as ``"solid"``."""
    register("svk-beam", make_beam, settings=BeamSettings, defaults=BEAM_DEFAULTS)
    register("solid", make_solid, settings=SolidSettings, defaults=SOLID_DEFAULTS)


@idbench.hookimpl
def register_commands(register: Callable[[str, Any], None]) -> None:
    """Register ``idbench calibrate``, ``mesh`` and ``check``.

    ``calibrate``: the beam's effective-E map; ``mesh``: tetrahedral meshes of
    a surface file; ``check``: a body TOML on each of its meshes.
    """
    register("calibrate", CALIBRATE)
    register("mesh", MESH)
    register("check", CHECK)


@idbench.hookimpl
def register_versions(register: Callable[[str, str], None]) -> None:
    """Report the libraries the solutions depend on: scikit-fem and the solvers."""
    import importlib.metadata

    for package in ("scikit-fem", "pypardiso", "numba"):
        try:
            register(package, importlib.metadata.version(package))
        except importlib.metadata.PackageNotFoundError:
            continue


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
    mesh_help=(
        "NXxNYxNZ: divisions of the box along x, y, z (each hex in 6 tets); "
        "rom:NXxNYxNZ[:MODES[:SAMPLING]]: a reduced model of that mesh (as the "
        "solid's), from 14 end tractions"
    ),
)
"""The study's comparison (docs/design.md section 1): what ``idbench compare`` runs."""


SOLID_DEFAULTS = idbench.ModelDefaults(
    truth_mesh="16000",
    meshes=("200", "500", "1000"),
    scenarios=("grasp-lift",),
    prior=(2000.0, 2000.0),
    quick={"truth_mesh": "1000", "meshes": ("200", "500")},
    shorthands={"body": ("body", "body TOML path or shipped name (liver, kidney)")},
    mesh_help=(
        "a node count N (the body's mesh *-nN, else generated), a mesh file name "
        "stem, truth, or a mesh file; rom:MESH[:MODES[:SAMPLING]]: a reduced "
        "model of mesh MESH, MODES POD modes (or a share < 1 of the snapshots' "
        "energy left out), SAMPLING the ECSW fit (< 1), a cap on the sampled "
        "elements (a whole number) or all, from the body's [design] paths "
        "(rom:16000:40)"
    ),
)
"""The shipped liver (settings' default body): meshes by node count, grasp-lift."""

"""Built-in model plugin: the St Venant-Kirchhoff beam and general solid bodies.

Folders: ``tools`` -> ``models`` -> ``bodies`` -> ``fem`` (each imports only
those after it); the names of ``__all__`` are imported at first use.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import idbench
from idbench_fem.exports import HOME, load
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




__all__ = ["BEAM_DEFAULTS", "SCENARIOS", "SOLID_DEFAULTS", *sorted(HOME)]


def __getattr__(name: str) -> Any:
    """A name of ``__all__``, imported from its module at first use (PEP 562)."""
    return load(name)

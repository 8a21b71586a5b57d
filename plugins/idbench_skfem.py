"""Deprecated: the FE plugin is now :mod:`idbench_fem` (this name goes in 0.2).

A module, not a package (so that git sees the old package's files move).
``from idbench_skfem import X`` keeps working for the public names of
:mod:`idbench_fem` (its ``__all__``), and the old module paths
(``idbench_skfem.model``, ``idbench_skfem.mesh``, ...) still import, as the
modules of the new layout. Importing this module warns once. It registers no
plugin: the entry point ``fem`` names :mod:`idbench_fem` alone, and the hook
implementations are not re-exported here.
"""

from __future__ import annotations

import importlib
import sys
import warnings
from typing import Any

import idbench_fem

warnings.warn(
    "idbench_skfem is deprecated and will be removed in idbench 0.2; "
    "import idbench_fem instead",
    DeprecationWarning,
    stacklevel=2,
)

MOVED = {
    "assembly": "idbench_fem.fem.svk_assembly",
    "batched": "idbench_fem.fem.batched",
    "bodies": "idbench_fem.bodies.catalog",
    "body": "idbench_fem.bodies.description",
    "calibrate": "idbench_fem.tools.calibrate",
    "commands": "idbench_fem.tools.commands",
    "geometry": "idbench_fem.bodies.geometry",
    "helpers": "idbench_fem.fem.step_workers",
    "kernels": "idbench_fem.fem.kernels",
    "loads": "idbench_fem.bodies.loads",
    "materials": "idbench_fem.fem.materials",
    "mesh": "idbench_fem.bodies.box",
    "model": "idbench_fem.models.beam",
    "newton": "idbench_fem.fem.newton",
    "probes": "idbench_fem.fem.interpolation",
    "regions": "idbench_fem.models.beam",
    "resolve": "idbench_fem.bodies.resolve",
    "scenarios": "idbench_fem.models.beam_scenarios",
    "settings": "idbench_fem.models.beam_settings",
    "solid": "idbench_fem.models.solid",
    "solid_assembly": "idbench_fem.fem.law_assembly",
    "solid_settings": "idbench_fem.models.solid_settings",
    "solidmesh": "idbench_fem.bodies.mesh",
    "solver": "idbench_fem.fem.solver",
}
"""Old module name -> the module of the new layout it now is."""

for _old, _new in MOVED.items():  # ``import idbench_skfem.model`` finds these
    sys.modules[f"{__name__}.{_old}"] = importlib.import_module(_new)

__all__ = list(idbench_fem.__all__)


def __getattr__(name: str) -> Any:
    """A public name of :mod:`idbench_fem`, or an old module (PEP 562)."""
    if name in MOVED:
        return sys.modules[f"{__name__}.{name}"]
    if name in idbench_fem.__all__:
        return getattr(idbench_fem, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

"""Built-in model plugin: the scikit-fem St Venant-Kirchhoff cantilever beam."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import idbench
from idbench_skfem.scenarios import SCENARIOS


@idbench.hookimpl
def register_scenarios(register: Callable[[Any], None]) -> None:
    """Register the beam's load paths (bend-y, bend-z, stretch-x, mixed-30/60)."""
    for scenario in SCENARIOS:
        register(scenario)


@idbench.hookimpl
def register_models(register: Callable[[str, Callable[..., Any]], None]) -> None:
    """Register the St Venant-Kirchhoff cantilever as ``"svk-beam"``."""
    from idbench_skfem.model import make_model

    register("svk-beam", make_model)

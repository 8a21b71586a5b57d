"""idbench: compare parameter estimators on coarse finite-element soft bodies.

The public API is what this module exports; plugins import only from here.
"""

from __future__ import annotations

from idbench.interfaces import (
    BatchModel,
    Cost,
    Diverged,
    Estimate,
    Estimator,
    ForwardModel,
    ModelFailure,
    ModelSpec,
    Observation,
    ParameterSpec,
    Prior,
    SensitiveModel,
    Skipped,
)
from idbench.plugins import (
    PluginError,
    Registry,
    build_registry,
    get_plugin_manager,
    hookimpl,
)
from idbench.scenario import Scenario, Sparsity

__version__ = "0.1.0"

__all__ = [
    "BatchModel",
    "Cost",
    "Diverged",
    "Estimate",
    "Estimator",
    "ForwardModel",
    "ModelFailure",
    "ModelSpec",
    "Observation",
    "ParameterSpec",
    "PluginError",
    "Prior",
    "Registry",
    "Scenario",
    "SensitiveModel",
    "Skipped",
    "Sparsity",
    "__version__",
    "build_registry",
    "get_plugin_manager",
    "hookimpl",
]

"""idbench: compare parameter estimators on coarse finite-element soft bodies.

The public API is what this module exports; plugins import only from here.
"""

from __future__ import annotations

from typing import Any

from idbench.config import ConfigError
from idbench.filter import Analysis, Filter, noise_matrix
from idbench.interfaces import (
    BatchModel,
    BoundingBoxModel,
    CellDataModel,
    Cost,
    Diverged,
    Estimate,
    Estimator,
    FieldModel,
    ForwardModel,
    ModelDefaults,
    ModelFailure,
    ModelSpec,
    NodeCountModel,
    Observation,
    ObservationNeedsModel,
    ParameterSpec,
    Prior,
    ProbedModel,
    ReactionModel,
    SensitiveModel,
    Skipped,
    SurfaceModel,
    TargetModel,
    VolumeModel,
)
from idbench.lowrank import LowRankCovariance
from idbench.occlusion import MaskedModel
from idbench.plugins import (
    Command,
    PluginError,
    Registry,
    build_registry,
    get_plugin_manager,
    hookimpl,
)
from idbench.scenario import Scenario, Sparsity
from idbench.transforms import TRANSFORMS, IdentityTransform, LogTransform

__version__ = "0.1.0"

_LAZY = {
    "CompareConfig": "idbench.config",
    "compare": "idbench.sweep",
    "effective_path": "idbench.effective",
    "shape_error": "idbench.metrics",
    "simulate_path": "idbench.truth",
    "simulate_truth": "idbench.truth",
}


def __getattr__(name: str) -> Any:
    """The heavier parts of the public API, imported on first use."""
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'idbench' has no attribute {name!r}")


__all__ = [
    "TRANSFORMS",
    "Analysis",
    "BatchModel",
    "BoundingBoxModel",
    "CellDataModel",
    "Command",
    "CompareConfig",
    "ConfigError",
    "Cost",
    "Diverged",
    "Estimate",
    "Estimator",
    "FieldModel",
    "Filter",
    "ForwardModel",
    "IdentityTransform",
    "LogTransform",
    "LowRankCovariance",
    "MaskedModel",
    "ModelDefaults",
    "ModelFailure",
    "ModelSpec",
    "NodeCountModel",
    "Observation",
    "ObservationNeedsModel",
    "ParameterSpec",
    "PluginError",
    "Prior",
    "ProbedModel",
    "Registry",
    "Scenario",
    "ReactionModel",
    "SensitiveModel",
    "Skipped",
    "SurfaceModel",
    "TargetModel",
    "Sparsity",
    "VolumeModel",
    "__version__",
    "build_registry",
    "compare",
    "effective_path",
    "noise_matrix",
    "get_plugin_manager",
    "hookimpl",
    "shape_error",
    "simulate_path",
    "simulate_truth",
]

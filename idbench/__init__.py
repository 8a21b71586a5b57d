"""idbench: compare parameter estimators on coarse finite-element soft bodies.

The public API is what this module exports; plugins import only from here.
"""

from __future__ import annotations

from idbench.calibrate.effective import effective_path
from idbench.core.interfaces import (
    Cost,
    Diverged,
    Estimate,
    Estimator,
    ForwardModel,
    ModelDefaults,
    ModelFailure,
    ModelSpec,
    Observation,
    ParameterSpec,
    Prior,
    Skipped,
)
from idbench.core.observation_model import ObservationModel
from idbench.core.optional import (
    BatchModel,
    BoundingBoxModel,
    CellDataModel,
    DiscrepancyModel,
    FieldModel,
    InputsModel,
    LoadScalingModel,
    MarkerLimitModel,
    NodeCountModel,
    ObservationNeedsModel,
    ProbedModel,
    ReactionModel,
    SensitiveModel,
    SurfaceModel,
    TargetModel,
    VolumeModel,
)
from idbench.core.scenario import Scenario, Sparsity
from idbench.core.version import __version__
from idbench.estimate.filter import Analysis, Filter, noise_matrix
from idbench.estimate.lowrank import LowRankCovariance
from idbench.estimate.transforms import TRANSFORMS, IdentityTransform, LogTransform
from idbench.observe.occlusion import MaskedModel
from idbench.observe.surface import closest_on_triangles
from idbench.plan.config import CompareConfig, ConfigError
from idbench.registry.registry import (
    Command,
    PluginError,
    Registry,
    build_registry,
    get_plugin_manager,
    hookimpl,
)
from idbench.run.compare import compare
from idbench.score.metrics import shape_error
from idbench.truth.simulate import simulate_path, simulate_truth

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
    "DiscrepancyModel",
    "Diverged",
    "Estimate",
    "Estimator",
    "FieldModel",
    "Filter",
    "ForwardModel",
    "IdentityTransform",
    "InputsModel",
    "LoadScalingModel",
    "LogTransform",
    "LowRankCovariance",
    "MarkerLimitModel",
    "MaskedModel",
    "ModelDefaults",
    "ModelFailure",
    "ModelSpec",
    "NodeCountModel",
    "Observation",
    "ObservationModel",
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
    "closest_on_triangles",
    "compare",
    "effective_path",
    "noise_matrix",
    "get_plugin_manager",
    "hookimpl",
    "shape_error",
    "simulate_path",
    "simulate_truth",
]

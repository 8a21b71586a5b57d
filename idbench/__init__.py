"""idbench: compare parameter estimators on coarse finite-element soft bodies.

The public API is what this module exports; plugins import only from here.
"""

from __future__ import annotations

from idbench.calibrate.design import fine_path
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
    DiagnosedModel,
    DiscrepancyModel,
    FieldModel,
    LoadScalingModel,
    NodeCountModel,
    ObservationNeedsModel,
    ProbedModel,
    ReactionModel,
    ReducedOrderModel,
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
from idbench.store.files import stable_hash
from idbench.truth.cache import cache_dir, read_entry, write_entry
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
    "DiagnosedModel",
    "DiscrepancyModel",
    "Diverged",
    "Estimate",
    "Estimator",
    "FieldModel",
    "Filter",
    "ForwardModel",
    "IdentityTransform",
    "LoadScalingModel",
    "LogTransform",
    "LowRankCovariance",
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
    "ReducedOrderModel",
    "SensitiveModel",
    "Skipped",
    "SurfaceModel",
    "TargetModel",
    "Sparsity",
    "VolumeModel",
    "__version__",
    "build_registry",
    "cache_dir",
    "closest_on_triangles",
    "compare",
    "effective_path",
    "fine_path",
    "noise_matrix",
    "read_entry",
    "get_plugin_manager",
    "hookimpl",
    "shape_error",
    "simulate_path",
    "simulate_truth",
    "stable_hash",
    "write_entry",
]

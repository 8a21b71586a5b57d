"""idbench: compare parameter estimators on coarse finite-element soft bodies.

The public API is what this module exports; plugins import only from here.
"""

from __future__ import annotations

from idbench.calibrate.design import fine_path
from idbench.calibrate.effective import effective_path
from idbench.core.capabilities import (
    adjoint_of,
    observation_jacobian_of,
    observation_points_of,
    parameter_field_of,
    sensitivity_of,
)
from idbench.core.field import ParameterField
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
    LOAD_FIGURES,
    AdjointModel,
    BatchModel,
    BoundingBoxModel,
    CellDataModel,
    DiagnosedModel,
    DiscrepancyModel,
    FieldModel,
    InputsModel,
    LinearObservationModel,
    LoadFiguresModel,
    LoadScalingModel,
    MarkerLimitModel,
    NodeCountModel,
    ObservationNeedsModel,
    ObservationPointsModel,
    ParameterFieldModel,
    PlacedPointsModel,
    ProbedModel,
    ReactionJacobianModel,
    ReactionModel,
    ReducedOrderModel,
    SensitiveModel,
    SurfaceJacobianModel,
    SurfaceModel,
    TargetModel,
    VolumeModel,
)
from idbench.core.scenario import Scenario, Sparsity
from idbench.core.version import __version__
from idbench.estimate.filter import Analysis, Filter, noise_matrix
from idbench.estimate.lowrank import LowRankCovariance
from idbench.estimate.prior import FieldPrior
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
    "LOAD_FIGURES",
    "TRANSFORMS",
    "AdjointModel",
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
    "FieldPrior",
    "Filter",
    "ForwardModel",
    "LoadFiguresModel",
    "IdentityTransform",
    "LinearObservationModel",
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
    "ObservationPointsModel",
    "ParameterField",
    "ParameterFieldModel",
    "ParameterSpec",
    "PlacedPointsModel",
    "PluginError",
    "Prior",
    "ProbedModel",
    "Registry",
    "Scenario",
    "ReactionJacobianModel",
    "ReactionModel",
    "ReducedOrderModel",
    "SensitiveModel",
    "Skipped",
    "SurfaceJacobianModel",
    "SurfaceModel",
    "TargetModel",
    "Sparsity",
    "VolumeModel",
    "__version__",
    "adjoint_of",
    "build_registry",
    "cache_dir",
    "closest_on_triangles",
    "compare",
    "effective_path",
    "fine_path",
    "noise_matrix",
    "observation_jacobian_of",
    "observation_points_of",
    "parameter_field_of",
    "read_entry",
    "get_plugin_manager",
    "hookimpl",
    "sensitivity_of",
    "shape_error",
    "simulate_path",
    "simulate_truth",
    "stable_hash",
    "write_entry",
]

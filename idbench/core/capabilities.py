"""Which optional members an object has: looked up here, and only here.

The core's protocols have optional members: a forward model's, an
estimator's (and the answer it returns), an observation model's, a model
settings class's, a plugin's, a progress callback's. Each is declared once:
a forward model's as a protocol of :mod:`idbench.core.optional`, mapped here
(:data:`OPTIONAL`), the others with their default and meaning in
:mod:`idbench.core.members` (``ESTIMATOR_OPTIONAL``, ``ESTIMATE_OPTIONAL``,
``OBSERVATION_OPTIONAL``, ``SETTINGS_OPTIONAL``, ``PLUGIN_OPTIONAL``,
``PROGRESS_OPTIONAL``). The core asks this module
instead of looking members up by name: each function gives the member, typed,
or None (a forward model's) or the declared default (the others') when the
object lacks it; a method that is not callable counts as lacking. A member is
looked up on the object given (a run's copy of a model answers for itself),
and only the member asked for (a property such as ``volume`` is computed only
when asked). :func:`idbench.registry.testing.check_model` checks the ones a
model has; :class:`idbench.core.view.ModelView` passes them through a wrapper.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, cast

import numpy as np

from idbench.core.field import ParameterField
from idbench.core.interfaces import FloatArray
from idbench.core.members import (
    ESTIMATE_OPTIONAL,
    ESTIMATOR_OPTIONAL,
    OBSERVATION_OPTIONAL,
    PLUGIN_OPTIONAL,
    PROGRESS_OPTIONAL,
    SETTINGS_OPTIONAL,
    Member,
)
from idbench.core.optional import (
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

# --- a forward model ----------------------------------------------------------

OPTIONAL: dict[str, type] = {
    "n_nodes": NodeCountModel,
    "probes": ProbedModel,
    "sensitivity": SensitiveModel,
    "step_many": BatchModel,
    "bounds": BoundingBoxModel,
    "volume": VolumeModel,
    "mesh": FieldModel,
    "displacement_field": FieldModel,
    "cell_data": CellDataModel,
    "surface": SurfaceModel,
    "reaction": ReactionModel,
    "targets": TargetModel,
    "marker_points": PlacedPointsModel,
    "target_points": PlacedPointsModel,
    "needs_observed": ObservationNeedsModel,
    "inputs": InputsModel,
    "max_markers": MarkerLimitModel,
    "observation_cov": DiscrepancyModel,
    "grid_cov": DiscrepancyModel,
    "targets_cov": DiscrepancyModel,
    "extrapolated": DiscrepancyModel,
    "load_scaling": LoadScalingModel,
    "load_figures": LoadFiguresModel,
    "parameter_field": ParameterFieldModel,
    "equilibrium_jvp": AdjointModel,
    "equilibrium_vjp": AdjointModel,
    "observation_jacobian": LinearObservationModel,
    "surface_jacobian": SurfaceJacobianModel,
    "reaction_jacobian": ReactionJacobianModel,
    "observation_points": ObservationPointsModel,
    "reduces": ReducedOrderModel,
    "diagnostics": DiagnosedModel,
    "diagnostic_warning": DiagnosedModel,
}
"""Each optional member of a forward model and the protocol that declares it."""

METHODS = frozenset(
    {
        "probes",
        "sensitivity",
        "step_many",
        "mesh",
        "displacement_field",
        "cell_data",
        "surface",
        "reaction",
        "targets",
        "observation_cov",
        "grid_cov",
        "targets_cov",
        "load_figures",
        "equilibrium_jvp",
        "equilibrium_vjp",
        "observation_jacobian",
        "surface_jacobian",
        "reaction_jacobian",
        "observation_points",
        "diagnostics",
        "diagnostic_warning",
    }
)
"""The optional members that are methods (the others are values)."""


def member(model: Any, name: str) -> Any:
    """The optional member ``name`` of ``model`` (see :data:`OPTIONAL`), or None.

    None also for a method that is not callable.

    Raises
    ------
    KeyError
        If ``name`` is no declared optional member.
    """
    if name not in OPTIONAL:
        raise KeyError(
            f"{name!r} is no optional model member; declared: {', '.join(OPTIONAL)}"
        )
    value = getattr(model, name, None)
    if name in METHODS and not callable(value):
        return None
    return value


def given(model: Any) -> dict[str, Any]:
    """The optional members ``model`` defines (not None), usable or not, by name."""
    found = {name: getattr(model, name, None) for name in OPTIONAL}
    return {name: value for name, value in found.items() if value is not None}


def present(model: Any) -> dict[str, Any]:
    """The optional members ``model`` has (usable: methods callable), by name."""
    found = {name: member(model, name) for name in OPTIONAL}
    return {name: value for name, value in found.items() if value is not None}


def needs_observed_of(model: Any) -> tuple[str, ...]:
    """Members an observation of ``model`` must use one of (empty: none needed).

    See :class:`~idbench.core.optional.ObservationNeedsModel`.
    """
    value = member(model, "needs_observed")
    return tuple(str(v) for v in value) if value else ()


def inputs_of(model: Any) -> tuple[str, ...]:
    """Members of ``model`` that give its input, not a measurement (empty: none).

    See :class:`~idbench.core.optional.InputsModel`.
    """
    value = member(model, "inputs")
    return tuple(str(v) for v in value) if value else ()


def max_markers_of(model: Any) -> int | None:
    """The most markers ``model`` can place, or None where it does not say.

    See :class:`~idbench.core.optional.MarkerLimitModel`.
    """
    value = member(model, "max_markers")
    return None if value is None else int(value)


def n_nodes_of(model: Any) -> int | None:
    """The model's mesh size (:class:`~idbench.core.optional.NodeCountModel`)."""
    value: int | None = member(model, "n_nodes")
    return value


def probes_of(model: Any) -> Callable[[FloatArray], dict[str, float]] | None:
    """The model's ``probes`` (:class:`~idbench.core.optional.ProbedModel`)."""
    value: Callable[[FloatArray], dict[str, float]] | None = member(model, "probes")
    return value


StepLike = Callable[[FloatArray, int, FloatArray], FloatArray]
"""The call of ``sensitivity`` and ``step_many``: (theta(s), k, state(s)) -> array."""


def sensitivity_of(model: Any) -> StepLike | None:
    """The model's ``sensitivity`` (:class:`~idbench.core.optional.SensitiveModel`).

    None where the model has none.
    """
    return cast("StepLike | None", member(model, "sensitivity"))


def step_many_of(model: Any) -> StepLike | None:
    """The model's ``step_many`` (:class:`~idbench.core.optional.BatchModel`)."""
    return cast("StepLike | None", member(model, "step_many"))


def bounds_of(model: Any) -> Any:
    """The model's ``bounds``, as it gives them.

    See :class:`~idbench.core.optional.BoundingBoxModel`.
    """
    return member(model, "bounds")


def volume_of(model: Any) -> Any:
    """The model's ``volume``, as given.

    See :class:`~idbench.core.optional.VolumeModel`.
    """
    return member(model, "volume")


def field_model(model: Any) -> FieldModel | None:
    """``model`` if it has ``mesh`` and ``displacement_field``, else None.

    See :class:`~idbench.core.optional.FieldModel`.
    """
    if member(model, "mesh") is None or member(model, "displacement_field") is None:
        return None
    return cast(FieldModel, model)


def cell_data_of(model: Any) -> Callable[[], dict[str, FloatArray]] | None:
    """The model's ``cell_data`` (:class:`~idbench.core.optional.CellDataModel`)."""
    value: Callable[[], dict[str, FloatArray]] | None = member(model, "cell_data")
    return value


def parameter_field_of(model: Any) -> ParameterField | None:
    """The model's ``parameter_field``, None where its parameters are no field.

    See :class:`~idbench.core.optional.ParameterFieldModel`.
    """
    value: ParameterField | None = member(model, "parameter_field")
    return value


def adjoint_of(model: Any) -> AdjointModel | None:
    """``model`` if it has ``equilibrium_jvp`` and ``equilibrium_vjp``, else None.

    See :class:`~idbench.core.optional.AdjointModel`.
    """
    both = ("equilibrium_jvp", "equilibrium_vjp")
    if any(member(model, name) is None for name in both):
        return None
    return cast(AdjointModel, model)


def observation_jacobian_of(model: Any) -> Callable[..., Any] | None:
    """The model's ``observation_jacobian`` (:class:`LinearObservationModel`)."""
    return cast("Callable[..., Any] | None", member(model, "observation_jacobian"))


def observation_points_of(model: Any) -> Callable[[int], FloatArray] | None:
    """The model's ``observation_points`` (:class:`ObservationPointsModel`)."""
    return cast(
        "Callable[[int], FloatArray] | None", member(model, "observation_points")
    )


def observation_cov_of(model: Any) -> Callable[[FloatArray], FloatArray] | None:
    """The corrected model's ``observation_cov`` (:class:`DiscrepancyModel`)."""
    value: Callable[[FloatArray], FloatArray] | None = member(model, "observation_cov")
    return value


def extrapolated_of(model: Any) -> int:
    """Predictions a corrected model made beyond its calibration (0: none, or no count).

    See :class:`~idbench.core.optional.DiscrepancyModel`.
    """
    return int(member(model, "extrapolated") or 0)


def marker_points_of(model: Any) -> FloatArray | None:
    """The model's markers' undeformed positions (M, 3), floats, or None.

    See :class:`~idbench.core.optional.PlacedPointsModel`.
    """
    value = member(model, "marker_points")
    return None if value is None else np.asarray(value, dtype=float).reshape(-1, 3)


def target_points_of(model: Any) -> FloatArray | None:
    """The model's targets' undeformed positions (T, 3), floats, or None.

    See :class:`~idbench.core.optional.PlacedPointsModel`.
    """
    value = member(model, "target_points")
    return None if value is None else np.asarray(value, dtype=float).reshape(-1, 3)


def reduces_of(model: Any) -> str | None:
    """The mesh a reduced-order model approximates, or None (no such model).

    See :class:`~idbench.core.optional.ReducedOrderModel`.
    """
    value = member(model, "reduces")
    return None if value is None else str(value)


def diagnostics_of(model: Any) -> tuple[dict[str, float], str]:
    """A model's report on its own run: columns and a warning (empty: none).

    See :class:`~idbench.core.optional.DiagnosedModel`.
    """
    columns, warning = member(model, "diagnostics"), member(model, "diagnostic_warning")
    found = {str(k): float(v) for k, v in (columns() if columns else {}).items()}
    return found, str(warning() if warning else "")


def requirement_met(model: Any, name: str) -> bool:
    """Whether ``model`` has a callable member ``name`` (an observation's ``requires``).

    An observation model names the forward-model methods it calls
    (:attr:`~idbench.core.observation_model.ObservationModel.requires`): the
    protocol's own, a declared optional one, or one of a plugin's models that
    the core does not know; so this is looked up by name.
    """
    return callable(getattr(model, name, None))


# --- the other objects: their members declared in idbench.core.members -------


def _optional(obj: Any, name: str, table: dict[str, Member], kind: str) -> Any:
    """``obj``'s member ``name`` of ``table``, or its default."""
    if name not in table:
        raise KeyError(
            f"{name!r} is no optional {kind} member; declared: {', '.join(table)}"
        )
    declared = table[name]
    value = getattr(obj, name, None)
    if value is None or (declared.method and not callable(value)):
        return declared.default
    return value


def estimator_member(estimator: Any, name: str) -> Any:
    """The estimator's (or its class's) ``name`` (:data:`ESTIMATOR_OPTIONAL`).

    Its default where it lacks it. Raises KeyError for an undeclared ``name``.
    """
    return _optional(estimator, name, ESTIMATOR_OPTIONAL, "estimator")


def estimate_member(estimate: Any, name: str) -> Any:
    """An estimate's ``name`` (:data:`ESTIMATE_OPTIONAL`), or its default."""
    return _optional(estimate, name, ESTIMATE_OPTIONAL, "estimate")


def observation_member(observation: Any, name: str) -> Any:
    """An observation model's ``name`` (:data:`OBSERVATION_OPTIONAL`), or default."""
    return _optional(observation, name, OBSERVATION_OPTIONAL, "observation model")


def settings_member(settings: Any, name: str) -> Any:
    """A settings object's (or class's) ``name`` (:data:`SETTINGS_OPTIONAL`).

    Its default where it lacks it.
    """
    return _optional(settings, name, SETTINGS_OPTIONAL, "settings")


def by_default(estimator: Any) -> bool:
    """Whether a comparison that names no estimators runs this one."""
    return bool(estimator_member(estimator, "by_default"))


def is_reference(estimator: Any) -> bool:
    """Whether the estimator (class) gives a run's reference value."""
    return bool(estimator_member(estimator, "reference"))


def handles_nan(estimator: Any) -> bool:
    """Whether the estimator takes observations with NaN (occluded) entries."""
    return bool(estimator_member(estimator, "handles_nan"))


def correction_of(estimator: Any) -> str:
    """The estimator's ``correction`` setting (``"none"`` without one)."""
    return str(estimator_member(estimator, "correction"))


def estimate_solves_of(estimator: Any) -> Callable[[int, int, int], int] | None:
    """The estimator's ``estimate_solves`` (None: it gives no guess)."""
    value: Callable[[int, int, int], int] | None = estimator_member(
        estimator, "estimate_solves"
    )
    return value


def ensemble_of(estimator: Any) -> Any:
    """The estimator's ``ensemble`` as it gives it, or None.

    A property that raises AttributeError (no run yet) counts as lacking;
    any other exception propagates.
    """
    return estimator_member(estimator, "ensemble")


def innovation_of(estimate: Any, estimator: Any) -> Any:
    """The step's innovation (nu, S): the estimate's, else the estimator's, or None."""
    found = estimate_member(estimate, "innovation")
    return found if found is not None else estimator_member(estimator, "innovation")


def state_of(estimate: Any) -> Any:
    """The model state an estimate reports, or None."""
    return estimate_member(estimate, "state")


def needs_theta_of(observation: Any) -> bool:
    """Whether an observation model's prediction uses theta itself."""
    return bool(observation_member(observation, "needs_theta"))


def observation_check_of(observation: Any) -> Callable[[Any], None] | None:
    """An observation model's ``check(model)`` (None without one)."""
    value: Callable[[Any], None] | None = observation_member(observation, "check")
    return value


def plugin_version_of(plugin: Any) -> str:
    """A plugin object's ``__version__`` (``""`` without one)."""
    return str(_optional(plugin, "__version__", PLUGIN_OPTIONAL, "plugin"))


def tick_of(progress: Any) -> Callable[[], None] | None:
    """A progress callback's ``tick`` (None without one, or without a callback)."""
    value: Callable[[], None] | None = _optional(
        progress, "tick", PROGRESS_OPTIONAL, "progress"
    )
    return value


# --- whether a class implements a protocol ----------------------------------------


def is_placeholder(value: Any) -> bool:
    """Whether a class member is marked ``@abc.abstractmethod`` (abc's own test)."""
    return bool(getattr(value, "__isabstractmethod__", False))



def protocol_members(protocol: type) -> dict[str, bool]:
    """The members a :class:`typing.Protocol` declares, own and inherited.

    Name -> whether it is a method (else an attribute or a property); the
    private ones left out.
    """
    out: dict[str, bool] = {}
    for base in reversed(protocol.__mro__):
        if base is object or base.__module__ == "typing":
            continue
        own = vars(base)
        annotated = own.get("__annotations__", {})
        for name in [*annotated, *own]:
            value = own.get(name)
            declared = name in annotated or isinstance(value, property)
            if not name.startswith("_") and (declared or callable(value)):
                out[name] = callable(value)
    return out


def lacking(cls: type, protocol: type) -> list[str]:
    """The members of ``protocol`` that the class ``cls`` lacks (empty: none).

    A method must be callable on the class; an attribute must be a class
    attribute (a property, a field's default) or a dataclass field.
    """
    fields = set()
    if dataclasses.is_dataclass(cls):
        fields = {f.name for f in dataclasses.fields(cls)}
    out = []
    for name, method in protocol_members(protocol).items():
        value = getattr(cls, name, None)
        if (not callable(value)) if method else (value is None and name not in fields):
            out.append(name)
    return out


def load_figures_of(model: Any) -> Callable[[], dict[str, float]] | None:
    """The model's ``load_figures``.

    See :class:`~idbench.core.optional.LoadFiguresModel`.
    """
    value: Callable[[], dict[str, float]] | None = member(model, "load_figures")
    return value

"""Which optional members an object has: declared here, looked up here, only here.

The core's protocols have optional members: a forward model's, an
estimator's (and the answer it returns), an observation model's, a model
settings class's, a plugin's, a progress callback's. Each is declared once,
in a table of this module: a forward model's as a protocol of
:mod:`idbench.core.interfaces` (:data:`OPTIONAL`), the others with their
default and meaning (:data:`ESTIMATOR_OPTIONAL`, :data:`ESTIMATE_OPTIONAL`,
:data:`OBSERVATION_OPTIONAL`, :data:`SETTINGS_OPTIONAL`,
:data:`PLUGIN_OPTIONAL`, :data:`PROGRESS_OPTIONAL`). The core asks this module
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
from dataclasses import dataclass
from typing import Any, cast

from idbench.core.interfaces import FloatArray
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
    "needs_observed": ObservationNeedsModel,
    "observation_cov": DiscrepancyModel,
    "grid_cov": DiscrepancyModel,
    "targets_cov": DiscrepancyModel,
    "extrapolated": DiscrepancyModel,
    "load_scaling": LoadScalingModel,
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


def observation_cov_of(model: Any) -> Callable[[FloatArray], FloatArray] | None:
    """The corrected model's ``observation_cov`` (:class:`DiscrepancyModel`)."""
    value: Callable[[FloatArray], FloatArray] | None = member(model, "observation_cov")
    return value


def extrapolated_of(model: Any) -> int:
    """Predictions a corrected model made beyond its calibration (0: none, or no count).

    See :class:`~idbench.core.optional.DiscrepancyModel`.
    """
    return int(member(model, "extrapolated") or 0)


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


# --- the other objects: a default and a meaning for each member -----------------


@dataclass(frozen=True)
class Member:
    """One optional member of an estimator, observation model, settings class, ...

    Attributes
    ----------
    default
        What the core takes when the object lacks it (or has None).
    meaning
        What it says, and who reads it.
    method
        Whether it is a method (a value that is not callable counts as lacking).
    """

    default: Any
    meaning: str
    method: bool = False


ESTIMATOR_OPTIONAL: dict[str, Member] = {
    "abstract": Member(
        False,
        "class attribute (idbench.Filter's class keyword abstract=True): a base "
        "for other estimators, not one itself; it cannot be registered",
    ),
    "reference": Member(
        False,
        "class attribute: True marks the estimator whose fit on a run's data is "
        "that run's reference value (E_ref); one registered estimator has it "
        "(idbench.registry.registry.Registry.reference_estimator)",
    ),
    "handles_nan": Member(
        False,
        "class attribute: True when the estimator takes observations with NaN "
        "(occluded) entries; otherwise such a run is refused in one line "
        "(idbench.observe.occlusion.refusal); idbench.Filter masks them",
    ),
    "seed": Member(
        None,
        "a setting (field) seeding the estimator's own draws; the harness gives "
        "each run its seed unless the user set one",
    ),
    "innovation": Member(
        None,
        "(v, S) after an observed step: the innovation v (m,) of the forecast "
        "and its covariance S (m, m); the traces' nis column is v^T S^-1 v "
        "(an Estimate's own innovation, if it has one, is read first)",
    ),
    "estimate_solves": Member(
        None,
        "estimate_solves(n_state, p, steps) -> int: the forward steps a run is "
        "expected to take (0 for a run start() would skip), for --dry-run and "
        "to start the costliest runs first; default 2 a step",
        method=True,
    ),
    "correction": Member(
        "none",
        'a setting: "approximation-error" hands the estimator the model '
        "corrected by its calibration (an idbench.DiscrepancyModel)",
    ),
    "ensemble": Member(
        None,
        "after the last step: the members (N, n), rows [u (model state), ...]; "
        "the targets' and the grid's predicted covariance is then the "
        "ensemble's (idbench.score.targets)",
    ),
}
"""Each optional member of an estimator (:class:`~idbench.core.interfaces.Estimator`).

:class:`idbench.Filter` gives each its default as a class attribute."""

ESTIMATE_OPTIONAL: dict[str, Member] = {
    "state": Member(
        None,
        "the estimator's own model state at the step, for the shape error "
        "(else one forward solve with the estimate)",
    ),
    "innovation": Member(None, "as the estimator's innovation, for this step"),
}
"""Each optional member of an estimator's answer (an :class:`~idbench.Estimate`)."""

OBSERVATION_OPTIONAL: dict[str, Member] = {
    "needs_theta": Member(
        False,
        "class attribute: True when predict() uses theta itself, not only the "
        "state (force): the prediction is carried in the estimators' state "
        "(idbench.observe.observed_model)",
    ),
}
"""Each optional member of an observation model.

See :class:`~idbench.core.observation_model.ObservationModel`."""

SETTINGS_OPTIONAL: dict[str, Member] = {
    "EXECUTION": Member(
        (),
        "class attribute: names of the settings that change where or how fast "
        "work runs, not its results (idbench.core.settings.execution_names)",
    ),
    "identity": Member(
        None,
        "identity() -> sequence: what of the settings identifies the data "
        "(default: every setting)",
        method=True,
    ),
    "proposed_defaults": Member(
        None,
        "proposed_defaults() -> idbench.ModelDefaults | None: the comparison "
        "these settings propose (idbench.core.settings.proposed_defaults)",
        method=True,
    ),
    "proposed_scenarios": Member(
        None,
        "proposed_scenarios() -> scenarios these settings bring "
        "(idbench.core.settings.proposed_scenarios)",
        method=True,
    ),
}
"""Each optional member of a model's settings class (or of an instance of it)."""

PLUGIN_OPTIONAL: dict[str, Member] = {
    "__version__": Member(
        "",
        "the plugin module's version, where its distribution does not say one",
    ),
}
"""Each optional member of a plugin object (the module an entry point names)."""

PROGRESS_OPTIONAL: dict[str, Member] = {
    "tick": Member(
        None,
        "tick(): called about once a second while workers run, so a display "
        "can move without news",
        method=True,
    ),
}
"""Each optional member of a comparison's ``progress`` callback."""


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

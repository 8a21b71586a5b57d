"""Which optional members a forward model has: looked up here, and only here.

Each optional member is declared as a protocol in :mod:`idbench.core.interfaces`
(:data:`OPTIONAL`). The core asks this module instead of looking members up
by name: each function gives the member, typed, or None when the model lacks
it (a method that is not callable counts as lacking). A member is looked up
on the object given (a run's copy of a model answers for itself), and only
the member asked for (a property such as ``volume`` is computed only when
asked). :func:`idbench.registry.testing.check_model` checks the ones a model has.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

from idbench.core.interfaces import (
    BatchModel,
    BoundingBoxModel,
    CellDataModel,
    FieldModel,
    FloatArray,
    LoadFiguresModel,
    NodeCountModel,
    ObservationNeedsModel,
    ProbedModel,
    ReactionModel,
    SensitiveModel,
    SurfaceModel,
    TargetModel,
    VolumeModel,
)

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
    "load_figures": LoadFiguresModel,
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
        "load_figures",
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

    See :class:`~idbench.core.interfaces.ObservationNeedsModel`.
    """
    value = member(model, "needs_observed")
    return tuple(str(v) for v in value) if value else ()


def n_nodes_of(model: Any) -> int | None:
    """The model's mesh size (:class:`~idbench.core.interfaces.NodeCountModel`)."""
    value: int | None = member(model, "n_nodes")
    return value


def probes_of(model: Any) -> Callable[[FloatArray], dict[str, float]] | None:
    """The model's ``probes`` (:class:`~idbench.core.interfaces.ProbedModel`)."""
    value: Callable[[FloatArray], dict[str, float]] | None = member(model, "probes")
    return value


StepLike = Callable[[FloatArray, int, FloatArray], FloatArray]
"""The call of ``sensitivity`` and ``step_many``: (theta(s), k, state(s)) -> array."""


def sensitivity_of(model: Any) -> StepLike | None:
    """The model's ``sensitivity`` (:class:`~idbench.core.interfaces.SensitiveModel`).

    None where the model has none.
    """
    return cast("StepLike | None", member(model, "sensitivity"))


def step_many_of(model: Any) -> StepLike | None:
    """The model's ``step_many`` (:class:`~idbench.core.interfaces.BatchModel`)."""
    return cast("StepLike | None", member(model, "step_many"))


def bounds_of(model: Any) -> Any:
    """The model's ``bounds``, as it gives them.

    See :class:`~idbench.core.interfaces.BoundingBoxModel`.
    """
    return member(model, "bounds")


def volume_of(model: Any) -> Any:
    """The model's ``volume``, as given.

    See :class:`~idbench.core.interfaces.VolumeModel`.
    """
    return member(model, "volume")


def field_model(model: Any) -> FieldModel | None:
    """``model`` if it has ``mesh`` and ``displacement_field``, else None.

    See :class:`~idbench.core.interfaces.FieldModel`.
    """
    if member(model, "mesh") is None or member(model, "displacement_field") is None:
        return None
    return cast(FieldModel, model)


def cell_data_of(model: Any) -> Callable[[], dict[str, FloatArray]] | None:
    """The model's ``cell_data`` (:class:`~idbench.core.interfaces.CellDataModel`)."""
    value: Callable[[], dict[str, FloatArray]] | None = member(model, "cell_data")
    return value


def load_figures_of(model: Any) -> Callable[[], dict[str, float]] | None:
    """The model's ``load_figures``.

    See :class:`~idbench.core.interfaces.LoadFiguresModel`.
    """
    value: Callable[[], dict[str, float]] | None = member(model, "load_figures")
    return value

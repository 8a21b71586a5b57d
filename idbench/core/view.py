"""A forward model seen through a wrapper: the protocol and the optional members.

A wrapper changes some of a model's members (an occluded observation's rows,
an observation model's h(x), a model without ``step_many``) and passes the
rest through. :class:`ModelView` passes the
:class:`~idbench.core.interfaces.ForwardModel` protocol through, member by
member, and every optional member declared in
:data:`idbench.core.capabilities.OPTIONAL` through a :class:`Delegated`
descriptor that asks :mod:`idbench.core.capabilities`: a member the wrapped
model lacks is absent from the view too (reading it raises AttributeError,
so capabilities reads None), and one it has is read when asked (a property
such as ``volume`` is computed only then, a counter such as ``extrapolated``
is live). A subclass overrides what it changes, and hides a member with
:class:`Absent`. Nothing else of the wrapped model is visible.
"""

from __future__ import annotations

from typing import Any

from idbench.core.capabilities import member
from idbench.core.interfaces import Cost, FloatArray, ForwardModel, ParameterSpec


def lacks(view: Any, name: str) -> AttributeError:
    """The error of reading an optional member ``name`` a view does not have."""
    return AttributeError(
        f"{type(view).__name__} of {type(view.model).__name__} has no {name}"
    )


class Delegated:
    """An optional member of the wrapped model, read through capabilities."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, view: Any, owner: type | None = None) -> Any:
        if view is None:
            return self
        value = member(view.model, self.name)
        if value is None:
            raise lacks(view, self.name)
        return value


class Absent:
    """An optional member a view never has, whatever the wrapped model has."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, view: Any, owner: type | None = None) -> Any:
        if view is None:
            return self
        raise lacks(view, self.name)


class ModelView:
    """A forward model that passes everything through to ``model``.

    Parameters
    ----------
    model
        The wrapped forward model.
    """

    def __init__(self, model: ForwardModel) -> None:
        self.model = model

    # --- the protocol ----------------------------------------------------------

    @property
    def parameters(self) -> ParameterSpec:
        """The model's parameters."""
        return self.model.parameters

    @property
    def n_steps(self) -> int:
        """The model's load steps."""
        return self.model.n_steps

    def reset(self) -> FloatArray:
        """The model's unloaded state."""
        return self.model.reset()

    def step(
        self, theta: FloatArray, k: int, state: FloatArray, *, substeps: int = 1
    ) -> FloatArray:
        """The model's step."""
        return self.model.step(theta, k, state, substeps=substeps)

    def observe(self, state: FloatArray) -> FloatArray:
        """The model's observation."""
        return self.model.observe(state)

    def grid(self, state: FloatArray) -> FloatArray:
        """The model's shape-error points."""
        return self.model.grid(state)

    def cost(self) -> Cost:
        """The model's cost."""
        return self.model.cost()

    def describe(self) -> dict[str, Any]:
        """The model's description."""
        return self.model.describe()

    # --- the optional members (idbench.core.capabilities.OPTIONAL) -------------

    n_nodes = Delegated()
    probes = Delegated()
    sensitivity = Delegated()
    step_many = Delegated()
    bounds = Delegated()
    volume = Delegated()
    load_figures = Delegated()
    mesh = Delegated()
    displacement_field = Delegated()
    cell_data = Delegated()
    surface = Delegated()
    reaction = Delegated()
    targets = Delegated()
    marker_points = Delegated()
    target_points = Delegated()
    needs_observed = Delegated()
    inputs = Delegated()
    max_markers = Delegated()
    observation_cov = Delegated()
    grid_cov = Delegated()
    targets_cov = Delegated()
    extrapolated = Delegated()
    load_scaling = Delegated()
    parameter_field = Delegated()
    equilibrium_jvp = Delegated()
    equilibrium_vjp = Delegated()
    observation_jacobian = Delegated()
    surface_jacobian = Delegated()
    reaction_jacobian = Delegated()
    observation_points = Delegated()
    reduces = Delegated()
    diagnostics = Delegated()
    diagnostic_warning = Delegated()

"""The optional members of a forward model, one protocol each.

A model implements :class:`~idbench.core.interfaces.ForwardModel`; where it
also has one of these members, it satisfies that member's protocol here.
:data:`idbench.core.capabilities.OPTIONAL` maps each member to its protocol,
and the core asks :mod:`idbench.core.capabilities` for them, never the model
by name.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from idbench.core.field import ParameterField
from idbench.core.interfaces import FloatArray, ForwardModel


@runtime_checkable
class SensitiveModel(ForwardModel, Protocol):
    """A forward model that also gives d(observations)/d(theta)."""

    def sensitivity(self, theta: FloatArray, k: int, state: FloatArray) -> FloatArray:
        """Jacobian of :meth:`observe` w.r.t. theta at the converged ``state``.

        Returns shape (m, p).
        """
        ...


@runtime_checkable
class SurfaceModel(ForwardModel, Protocol):
    """A forward model that can show its deformed boundary (for ``cloud``).

    Optional: the ``cloud`` observation model (:mod:`idbench.observe.cloud`)
    renders the truth's surface and measures each point's distance to an
    estimator's model surface through it.
    """

    def surface(self, state: FloatArray) -> tuple[FloatArray, NDArray[np.int64]]:
        """The deformed boundary at ``state``: vertices (V, 3), triangles (T, 3).

        Vertices are in model coordinates (reference position plus
        displacement); each triangle's vertex order gives its normal
        (right-hand rule), outward; the same orientation rule at every state.
        """
        ...


@runtime_checkable
class ReactionModel(ForwardModel, Protocol):
    """A forward model that reports the reaction force of its manipulation.

    Optional: the ``force`` observation model observes it.
    """

    def reaction(self, theta: FloatArray, k: int, state: FloatArray) -> FloatArray:
        """The reaction force (c,) at the converged ``state`` of step ``k``.

        The sum of the internal forces f_int(state; theta) at the constrained
        or driven nodes (what a force sensor on the tool or the support
        measures), per component; model force units (N for the built-ins).
        """
        ...


@runtime_checkable
class ObservationNeedsModel(ForwardModel, Protocol):
    """A forward model whose parameters are identifiable only from some observations.

    Optional: ``needs_observed`` names model members (``("reaction",)``) of
    which some observation block of every run must use one (require it, see
    :class:`~idbench.core.observation_model.ObservationModel`); a comparison
    that observes none of them is refused at plan time. A solid whose tool moves by a
    prescribed displacement declares ``("reaction",)``: its displacements do
    not depend on a homogeneous E, only the tool's force does.
    """

    @property
    def needs_observed(self) -> tuple[str, ...]:
        """Members of which an observation must use at least one (non-empty)."""
        ...


@runtime_checkable
class InputsModel(ForwardModel, Protocol):
    """A forward model some of whose members give its input, not a measurement.

    Optional: ``inputs`` names model members (``("reaction",)``) whose values
    the load path prescribes whatever theta is. A solid loaded by a force
    declares ``("reaction",)``: its support's reaction balances the applied
    load. An observation whose every block uses only such members cannot
    identify anything, and is refused at plan time.
    """

    @property
    def inputs(self) -> tuple[str, ...]:
        """Members whose values do not depend on the parameters (may be empty)."""
        ...


@runtime_checkable
class MarkerLimitModel(ForwardModel, Protocol):
    """A forward model that says how many markers it can place.

    Optional: a comparison asking for more markers (``obs_points``) than
    ``max_markers`` of any of its models is refused at plan time, before
    anything of that size is allocated.
    """

    @property
    def max_markers(self) -> int:
        """The most markers the model can place (its candidate points), >= 1."""
        ...


@runtime_checkable
class TargetModel(ForwardModel, Protocol):
    """A forward model with hidden targets (a tumour, points on a vessel).

    Optional: targets are never observed; every run scores the target
    registration error (TRE) between the model's targets moved with the
    estimate and the truth's (:mod:`idbench.score.targets`). Truth and model name
    the same undeformed target points (a body description's ``[targets]``).
    """

    def targets(self, state: FloatArray) -> FloatArray:
        """Displacements (T, 3) of the target points at ``state``, in metres.

        T = 0 (an empty (0, 3) array): the model has no targets this time
        (e.g. a body description without ``[targets]``); no TRE columns.
        """
        ...


@runtime_checkable
class PlacedPointsModel(ForwardModel, Protocol):
    """A forward model that says where its markers and its targets are.

    Optional: a run's stored scene (:mod:`idbench.store.surfaces`) places the
    displacements of ``observe`` and ``targets`` at these points, so that a
    report draws the markers (observed and predicted) and the targets (true
    and predicted, with their 95% regions) in the body.
    """

    @property
    def marker_points(self) -> FloatArray:
        """The markers' undeformed positions (M, 3), in model coordinates.

        In the order of :meth:`ForwardModel.observe`: marker i moves by its
        entries 3i..3i+2 (``observe(state)`` has 3M values).
        """
        ...

    @property
    def target_points(self) -> FloatArray:
        """The targets' undeformed positions (T, 3), in model coordinates.

        In the order of ``targets(state)`` (:class:`TargetModel`); (0, 3)
        for a model without targets.
        """
        ...


@runtime_checkable
class BatchModel(ForwardModel, Protocol):
    """A forward model that can also advance several parameter/state pairs at once.

    Optional: estimators that advance an ensemble (sigma points) call
    ``step_many`` when the model has it and fall back to r calls of
    :meth:`ForwardModel.step` otherwise (or when ``step_many`` raises
    :class:`ModelFailure`). A model may keep caches between calls (e.g.
    factorizations shared by nearby sigma points), but its results never
    depend on the order of calls beyond the Newton tolerance. A model is never
    shared between threads: use one per thread or process.
    """

    def step_many(self, thetas: FloatArray, k: int, states: FloatArray) -> FloatArray:
        """Solve load step ``k`` for r pairs: thetas (r, p), states (r, n) -> (r, n).

        Row i equals ``step(thetas[i], k, states[i])`` to the Newton tolerance
        (each meets the same convergence test; not necessarily bitwise).
        Raises :class:`ModelFailure` if any pair fails.
        """
        ...


@runtime_checkable
class NodeCountModel(ForwardModel, Protocol):
    """A forward model that says its mesh size (the tables' ``model_nodes``)."""

    @property
    def n_nodes(self) -> int:
        """Nodes of the mesh, a whole number >= 1."""
        ...


@runtime_checkable
class ProbedModel(ForwardModel, Protocol):
    """A forward model with named scalar outputs (e.g. a tip displacement).

    They are recorded per step for the truth in the traces table.
    """

    def probes(self, state: FloatArray) -> dict[str, float]:
        """Named finite scalars at ``state`` (names must not shadow a column)."""
        ...


@runtime_checkable
class BoundingBoxModel(ForwardModel, Protocol):
    """A forward model that says the bounding box of its undeformed body."""

    @property
    def bounds(self) -> FloatArray:
        """Array (2, d): the lower and the upper corner."""
        ...


@runtime_checkable
class VolumeModel(ForwardModel, Protocol):
    """A forward model that says the volume of its undeformed body."""

    @property
    def volume(self) -> float:
        """The volume, a finite number > 0."""
        ...


@runtime_checkable
class FieldModel(ForwardModel, Protocol):
    """A forward model that can show its displacement field (``idbench simulate``)."""

    def mesh(self) -> tuple[FloatArray, NDArray[np.int64]]:
        """Points (N, 3) and tetrahedra (T, 4) of the undeformed mesh."""
        ...

    def displacement_field(self, state: FloatArray) -> FloatArray:
        """Displacements of every node at ``state``, shape (N, 3)."""
        ...


@runtime_checkable
class CellDataModel(ForwardModel, Protocol):
    """A forward model with data per cell of :meth:`FieldModel.mesh` (region tags)."""

    def cell_data(self) -> dict[str, FloatArray]:
        """Arrays (T,) by name, written with every step of ``idbench simulate``."""
        ...


@runtime_checkable
class DiscrepancyModel(ForwardModel, Protocol):
    """A forward model corrected by a calibrated discrepancy (approximation error).

    Optional: the model a run with ``correction = "approximation-error"`` is
    handed (:mod:`idbench.calibrate.discrepancy`). Its predictions carry the
    discrepancy's mean, and these members give its covariance, so that the
    filters add it to R (:meth:`idbench.Filter.noise_cov`) and the scores to
    the predicted spread (:mod:`idbench.score.targets`).
    """

    def observation_cov(self, state: FloatArray) -> FloatArray:
        """Sigma (m, m): the discrepancy's covariance of the observation at state."""
        ...

    def grid_cov(self, state: FloatArray) -> FloatArray:
        """The discrepancy's covariance (G, d, d) of each shape-error point."""
        ...

    def targets_cov(self, state: FloatArray) -> FloatArray:
        """The discrepancy's covariance (T, 3, 3) of each hidden target."""
        ...

    @property
    def extrapolated(self) -> int:
        """Predictions so far asked beyond the calibrated load states (a warning)."""
        ...


@runtime_checkable
class LoadScalingModel(ForwardModel, Protocol):
    """A forward model that says whether its path scales with the load.

    Optional: ``load_scaling`` True declares that the state at step k with
    parameter theta (p = 1) depends on (k, theta) only through
    (k / K) / theta; False that it does not. Without it a calibration checks
    it on the model (:mod:`idbench.calibrate.discrepancy`).
    """

    @property
    def load_scaling(self) -> bool:
        """Whether the path depends on (k, theta) only through (k / K) / theta."""
        ...


LOAD_FIGURES: dict[str, str] = {
    "resultant": "N",
    "moment": "N m",
    "area": "m^2",
    "fixed_area": "m^2",
    "volume": "m^3",
    "mass": "kg",
}
"""The figures a :class:`LoadFiguresModel` reports, by name, with their units.

``resultant``: the magnitude of the sum of the scenario's external nodal
forces at the end of its load path; ``moment``: the magnitude of their
moment about the centroid of the fixed (supported) region; ``area``: the
loaded surface's area (0 for a body force); ``fixed_area``: the fixed
region's surface area; ``volume`` and ``mass``: the body's. A model may
report a subset, or other names (each a column ``load_NAME_ratio``).
"""


@runtime_checkable
class LoadFiguresModel(ForwardModel, Protocol):
    """A forward model that measures its scenario's load on its own mesh.

    Optional: a run stores, per figure, the ratio of its model's figure to
    the truth model's (columns ``load_NAME_ratio``, NaN where the truth's is
    0 or missing), and the summary flags the rows whose ratios differ from
    1 by more than 2%: on a coarse mesh of a curved body the same selector
    captures another area, and a lighter load looks like a stiffer body.
    """

    def load_figures(self) -> dict[str, float]:
        """Finite figures >= 0 by name (:data:`LOAD_FIGURES`: names and units).

        Of the whole load path's end load, in model units (SI for the
        built-ins); they do not depend on the parameters or the state.
        """
        ...


@runtime_checkable
class ParameterFieldModel(ForwardModel, Protocol):
    """A forward model whose parameters are one field's values on cells.

    Optional: field-aware estimators put a smoothness prior on the cells
    (:mod:`idbench.estimate.prior`) and localize by distance between cell
    centroids and observation points; the scores draw and measure the map
    (:mod:`idbench.score.maps`).
    """

    @property
    def parameter_field(self) -> ParameterField:
        """The cells (parameter j is the value on cell j) and the prior's settings."""
        ...


@runtime_checkable
class ReducedOrderModel(ForwardModel, Protocol):
    """A reduced-order model of a finer discretisation (say, POD of a fine mesh).

    Optional: ``reduces`` names the mesh spec it approximates. It is not
    that mesh, so a truth on a mesh of as many nodes as its ``n_nodes`` (the
    mesh it reduces) is allowed (:mod:`idbench.plan.validity`).
    """

    @property
    def reduces(self) -> str:
        """The mesh spec of the discretisation this model approximates."""
        ...


@runtime_checkable
class AdjointModel(ForwardModel, Protocol):
    """A forward model that gives products with its state's parameter derivative.

    Optional: at the converged state u_k of step k (equilibrium r(u, theta) =
    0, K = dr/du, G = dr/dtheta), du_k/dtheta = -K^-1 G. Where each step's
    equilibrium does not depend on the path to it, u_k depends on theta only
    through step k's equilibrium, so these are the derivatives of the whole
    path's state at step k. Each costs one solve with K (or K^T) per column.
    """

    def equilibrium_jvp(
        self, theta: FloatArray, k: int, state: FloatArray, v: FloatArray
    ) -> FloatArray:
        """(du/dtheta) v: v (p,) -> (n,), or (p, q) -> (n, q)."""
        ...

    def equilibrium_vjp(
        self, theta: FloatArray, k: int, state: FloatArray, w: FloatArray
    ) -> FloatArray:
        """w^T (du/dtheta), the adjoint: w (n,) -> (p,), or (n, q) -> (p, q).

        lambda = K^-T w, result -G^T lambda: one transposed solve a column.
        """
        ...


@runtime_checkable
class LinearObservationModel(ForwardModel, Protocol):
    """A forward model whose observation it can linearize at a state.

    Optional: h(u, theta) of step k, linearized as (H_u, H_theta), so that
    d h / d theta = H_u du/dtheta + H_theta (with :class:`AdjointModel`).
    """

    def observation_jacobian(
        self, theta: FloatArray, k: int, state: FloatArray
    ) -> tuple[Any, FloatArray]:
        """(H_u, H_theta): dh/du (m, n), sparse or dense, and dh/dtheta (m, p)."""
        ...


@runtime_checkable
class SurfaceJacobianModel(ForwardModel, Protocol):
    """A forward model that says how its surface vertices move with its state."""

    def surface_jacobian(self, state: FloatArray) -> Any:
        """D vec(vertices) / d state, (3V, n) sparse.

        Rows [v0x, v0y, v0z, v1x, ...] of :meth:`SurfaceModel.surface`'s
        vertices.
        """
        ...


@runtime_checkable
class ReactionJacobianModel(ForwardModel, Protocol):
    """A forward model that linearizes its reaction force (``force`` observations)."""

    def reaction_jacobian(
        self, theta: FloatArray, k: int, state: FloatArray
    ) -> tuple[Any, FloatArray]:
        """(d reaction / d state (c, n), d reaction / d theta (c, p))."""
        ...


@runtime_checkable
class ObservationPointsModel(ForwardModel, Protocol):
    """A forward model that says where its observed values are (localization)."""

    def observation_points(self, k: int) -> FloatArray:
        """(m, d): each observed value's position at step k; NaN rows: not local."""
        ...


@runtime_checkable
class DiagnosedModel(ForwardModel, Protocol):
    """A forward model that reports on its own accuracy over a run.

    Optional: after a run the harness adds ``diagnostics()`` to the run's row
    (one column each) and a non-empty ``diagnostic_warning()`` to its
    ``warning`` (the run is flagged). Both describe the run's copy of the
    model, so they cover the steps that run solved.
    """

    def diagnostics(self) -> dict[str, float]:
        """Named finite scalars on the run so far (an error estimate, ...)."""
        ...

    def diagnostic_warning(self) -> str:
        """Why this run's model is not to be trusted; "" if nothing says so."""
        ...

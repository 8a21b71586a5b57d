"""The optional members of a forward model, one protocol each.

A model implements :class:`~idbench.core.interfaces.ForwardModel`; where it
also has one of these members, it satisfies that member's protocol here.
:data:`idbench.core.capabilities.OPTIONAL` maps each member to its protocol,
and the core asks :mod:`idbench.core.capabilities` for them, never the model
by name.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

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

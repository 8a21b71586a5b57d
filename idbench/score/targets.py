"""Hidden targets: the target registration error (TRE) of a run, and its region.

A model with ``targets(state)`` (:class:`~idbench.core.optional.TargetModel`)
names points nobody observes (a tumour's centroid, points on a vessel). Each
step's ``tre_mm`` is the mean over the targets of the distance between the
target moved by the model with the estimator's state and moved by the truth
(:func:`idbench.score.metrics.target_registration_error`), in mm. At the end of a
run:

- ``tre_final_mm``: the last step's TRE;
- ``tre_max_final_mm``: the largest target's at the last step;
- ``target_std_final_mm``: the predicted spread of the target positions,
  sqrt(trace C_t) averaged over the targets (mm);
- ``tre_covered_final``: the share of targets whose true position lies in the
  95% region (chi-square, 3 dof) of the predicted N(prediction, C_t)
  (:func:`idbench.score.metrics.ellipsoid_covers`);
- ``target_cov_method``: how C_t was obtained. ``ensemble`` where the
  estimator exposes its members (an ``ensemble`` property (N, n), rows
  starting with the model state, as EnKF and ETKF do): the members' target
  positions' sample covariance. ``jacobian`` otherwise (RO-UKF, UKF, RLS,
  LMS, batch LS expose neither sigma-point states nor a state covariance):
  the parameter std propagated through a forward-difference Jacobian of the
  target map theta -> targets(path(theta) at step K) at the estimate,
  C_t = J diag(std^2) J^T (p + 1 path solves on the metrics model, not
  counted in the run's cost). With fewer parameters than 3 the region is flat
  and holds only a target on it: model (discretisation) error shows as not
  covered.

A model without targets gives no such columns and costs nothing.

Under the approximation-error correction (:mod:`idbench.calibrate.discrepancy`) the
model's targets and grid carry the calibrated mean discrepancy, and the
predicted covariance adds the discrepancy's own (``targets_cov`` /
``grid_cov`` of the corrected model) to the parameter's propagated one:
C = C_theta + Sigma_d. For the shape-error grid the same (:func:`grid_columns`):

- ``grid_std_final_mm``: sqrt(trace C) averaged over the grid points (mm);
- ``grid_covered_final``: the share of grid points whose true displacement
  lies in the 95% region of N(prediction, C) (as ``tre_covered_final``);
- ``grid_disc_std_final_mm``: the discrepancy's part alone (sqrt(trace
  Sigma_d), mean over points).

On a recording (``--data``, :mod:`idbench.store.recording`) the truth's targets are
the recording's held-out targets, and its held-out marker tracks score each
step's ``heldout_mm``: the mean distance (mm) between the model's markers
(``observe``) and the tracks, occluded (NaN) markers left out;
``heldout_final_mm`` at the last step.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from idbench.core.capabilities import adjoint_of, ensemble_of, member
from idbench.core.interfaces import FloatArray, ForwardModel, ModelFailure
from idbench.score import metrics
from idbench.truth.simulate import Truth, simulate_path

MM = 1000.0
"""Model length unit (m) to the tables' mm."""

FD_STEP = 1e-3
"""Relative step of the forward differences of the target map."""


def has_targets(model: ForwardModel, truth: Truth) -> bool:
    """Whether runs on ``model`` against ``truth`` are scored on targets.

    Both must have them: the model a ``targets`` member, the truth targets
    (T >= 1) probed from its states.
    """
    return member(model, "targets") is not None and truth.targets is not None


def step_tre_mm(model: ForwardModel, state: FloatArray, truth_targets: Any) -> float:
    """Mean TRE (mm) over the targets of ``model`` at ``state`` vs the truth's."""
    moved = _moved(model, state)
    return float(MM * metrics.target_registration_error(moved, truth_targets).mean())


def heldout_mm(model: ForwardModel, state: FloatArray, tracks: Any) -> float:
    """Mean distance (mm) of the model's markers at ``state`` to held-out tracks.

    ``tracks`` (3M,) are marker displacements, NaN where occluded (left out);
    NaN if none is visible or the sizes differ.
    """
    moved = np.asarray(model.observe(state), dtype=float).reshape(-1, 3)
    held = np.asarray(tracks, dtype=float).reshape(-1, 3)
    if moved.shape != held.shape:
        return float("nan")
    seen = np.isfinite(held).all(axis=1)
    if not seen.any():
        return float("nan")
    return float(MM * np.linalg.norm(moved[seen] - held[seen], axis=1).mean())


def empty_columns() -> dict[str, Any]:
    """The final target columns of a run that has none (NaN)."""
    return {
        "tre_final_mm": np.nan,
        "tre_max_final_mm": np.nan,
        "target_std_final_mm": np.nan,
        "tre_covered_final": np.nan,
        "target_cov_method": "",
    }


def final_scores(
    model: ForwardModel,
    estimator: Any,
    state: FloatArray,
    mean: FloatArray,
    std: FloatArray,
    truth_targets: FloatArray,
) -> tuple[dict[str, Any], FloatArray]:
    """The run row's target columns (see the module) at the last step.

    With them, the predicted covariance C (T, 3, 3) of each target that
    ``tre_covered_final`` and ``target_std_final_mm`` use (the discrepancy's
    added under a correction): the run's stored scene draws its 95% region.

    Parameters
    ----------
    model
        The metrics model (not the estimator's copy).
    estimator
        The estimator after its last update (asked for ``ensemble``).
    state
        The model state the last step was scored with (n,).
    mean, std
        The final estimate (p,).
    truth_targets
        The truth's target displacements at the last step (T, 3).
    """
    moved = _moved(model, state)
    true = np.asarray(truth_targets, dtype=float).reshape(moved.shape)
    tre = metrics.target_registration_error(moved, true)
    cov, how = covariance(model, estimator, state.size, mean, std)
    extra = member(model, "targets_cov")
    if extra is not None:  # the corrected model's discrepancy at the targets
        cov = cov + np.asarray(extra(state), dtype=float).reshape(cov.shape)
    covered = [
        metrics.ellipsoid_covers(true[t] - moved[t], cov[t]) for t in range(len(moved))
    ]
    spread = np.sqrt(np.clip(np.trace(cov, axis1=1, axis2=2), 0.0, None))
    return {
        "tre_final_mm": float(MM * tre.mean()),
        "tre_max_final_mm": float(MM * tre.max()),
        "target_std_final_mm": float(MM * spread.mean()),
        "tre_covered_final": float(np.mean(covered)),
        "target_cov_method": how,
    }, cov


def grid_columns(
    model: ForwardModel,
    estimator: Any,
    state: FloatArray,
    mean: FloatArray,
    std: FloatArray,
    truth_grid: FloatArray,
) -> dict[str, Any]:
    """The predictive uncertainty of the shape-error grid at the last step.

    Arguments as :func:`final_scores` (``truth_grid``: the truth's grid
    displacements (G, d)); the columns are the module's ``grid_*``.
    """
    pred = _grid(model, state)
    true = np.asarray(truth_grid, dtype=float).reshape(pred.shape)
    cov, _ = covariance(model, estimator, state.size, mean, std, _grid)
    disc = np.zeros_like(cov)
    extra = member(model, "grid_cov")
    if extra is not None:
        disc = np.asarray(extra(state), dtype=float).reshape(cov.shape)
    cov = cov + disc
    covered = [metrics.ellipsoid_covers(true[g] - pred[g], cov[g])
               for g in range(len(pred))]  # fmt: skip

    def spread(c: FloatArray) -> float:
        tr = np.clip(np.trace(c, axis1=1, axis2=2), 0.0, None)
        return float(MM * np.sqrt(tr).mean())

    return {
        "grid_std_final_mm": spread(cov),
        "grid_disc_std_final_mm": spread(disc),
        "grid_covered_final": float(np.mean(covered)),
    }


def covariance(
    model: ForwardModel, estimator: Any, n: int, mean: FloatArray, std: FloatArray,
    points: Callable[[Any, FloatArray], FloatArray] | None = None,
) -> tuple[FloatArray, str]:
    """Predicted covariance (T, 3, 3) of the targets at the last step, and how.

    From the estimator's ensemble if it has one (rows [u (n,), ...]), else the
    parameter std through a forward-difference Jacobian (see the module).
    NaN where the estimator gives no std. ``points(model, state)`` (P, d):
    other points than the targets (the grid: :func:`grid_columns`).
    """
    at = _moved if points is None else points
    members = _ensemble(estimator, n)
    if members is not None:
        moved = np.array([at(model, u) for u in members])
        d = moved - moved.mean(axis=0)
        cov = np.einsum("ntj,ntk->tjk", d, d) / (len(members) - 1)
        return cov, "ensemble"
    mean = np.asarray(mean, dtype=float)
    std = np.asarray(std, dtype=float)
    shape = at(model, np.zeros(n)).shape
    if not np.all(np.isfinite(std)):
        return np.full((shape[0], shape[1], shape[1]), np.nan), "jacobian"
    try:
        return _jacobian_covariance(model, mean, std, at), "jacobian"
    except ModelFailure:  # a perturbed path that does not solve: no region
        return np.full((shape[0], shape[1], shape[1]), np.nan), "jacobian"


ADJOINT_FROM = 8
"""Parameters from which a model's ``equilibrium_jvp`` gives the points' Jacobian
(one path and one multi-column solve) instead of p + 1 perturbed paths."""


def _jacobian_covariance(
    model: ForwardModel, mean: FloatArray, std: FloatArray,
    at: Callable[[Any, FloatArray], FloatArray],
) -> FloatArray:
    """J diag(std^2) J^T (P, d, d), J by forward differences of the point map.

    From :data:`ADJOINT_FROM` parameters on, a model with an adjoint
    (:class:`~idbench.core.optional.AdjointModel`) differences the point map
    along its state's derivative du/dtheta_j at the final state instead.
    """

    def points_at(theta: FloatArray) -> FloatArray:
        return at(model, simulate_path(model, theta)[-1])

    adjoint = adjoint_of(model) if mean.size >= ADJOINT_FROM else None
    if adjoint is not None:  # a field: one path and one solve, not p + 1 paths
        states = simulate_path(model, mean)
        u = states[-1]
        du = adjoint.equilibrium_jvp(mean, len(states), u, np.eye(mean.size))
        if np.shape(du) == (u.size, mean.size):
            base = at(model, u)
            jac = np.empty((*base.shape, mean.size))
            for j in range(mean.size):
                h = FD_STEP * max(abs(float(mean[j])), float(std[j]), 1e-300)
                jac[:, :, j] = (at(model, u + h * du[:, j]) - base) / h
            return np.asarray(np.einsum("tjp,p,tkp->tjk", jac, std**2, jac))
    base = points_at(mean)
    t, dim = base.shape
    jac = np.empty((t, dim, mean.size))
    for j in range(mean.size):
        h = FD_STEP * max(abs(float(mean[j])), float(std[j]), 1e-300)
        shifted = mean.copy()
        shifted[j] += h
        if not model.parameters.contains(shifted):
            shifted[j] -= 2 * h
            h = -h
        jac[:, :, j] = (points_at(shifted) - base) / h
    return np.asarray(np.einsum("tjp,p,tkp->tjk", jac, std**2, jac))


def _grid(model: Any, state: FloatArray) -> FloatArray:
    """``model.grid(state)`` (G, d), floats."""
    g = np.asarray(model.grid(state), dtype=np.float64)
    return g.reshape(len(g), -1)


def _moved(model: Any, state: FloatArray) -> FloatArray:
    """``model.targets(state)`` (T, 3), floats."""
    return np.asarray(model.targets(state), dtype=np.float64).reshape(-1, 3)


def _ensemble(estimator: Any, n: int) -> FloatArray | None:
    """The members' model states (N, n), or None if the estimator shows none."""
    try:
        rows = ensemble_of(estimator)
    except Exception:  # a property that fails: no ensemble to use
        return None
    if rows is None:
        return None
    rows = np.asarray(rows, dtype=float)
    if rows.ndim != 2 or rows.shape[0] < 2 or rows.shape[1] < n:
        return None
    members = rows[:, :n]
    return members if np.all(np.isfinite(members)) else None

"""The metrics of DESIGN.md section 5, defined once and used everywhere."""

from __future__ import annotations

import numpy as np

from idbench.interfaces import FloatArray

SETTLING_TOLERANCE = 0.05
"""Relative distance to the reference inside which an estimate has settled."""


def shape_error(model_grid: FloatArray, truth_grid: FloatArray) -> tuple[float, float]:
    """Distance between the grid moved by the model and by the truth.

    Both move the same undeformed grid points, so each point's distance is the
    norm of the difference of its two displacements.

    Parameters
    ----------
    model_grid, truth_grid
        Grid displacements, shape (G, 3).

    Returns
    -------
    tuple of float
        The sum over the G points (the paper's definition) and the mean.
    """
    a = np.asarray(model_grid, dtype=float)
    b = np.asarray(truth_grid, dtype=float)
    if a.shape != b.shape:
        raise ValueError(f"grid shapes differ: {a.shape} vs {b.shape}")
    d = np.linalg.norm(a - b, axis=-1)
    return float(d.sum()), float(d.mean())


def settling_step(
    estimates: FloatArray, reference: FloatArray, tol: float = SETTLING_TOLERANCE
) -> int | None:
    """First step after which every estimate stays within ``tol`` of the reference.

    Parameters
    ----------
    estimates
        Estimates per step, shape (K, p); row k-1 is step k.
    reference
        The reference value (E_ref), shape (p,).
    tol
        Relative tolerance; for p > 1 the worst parameter counts.

    Returns
    -------
    int or None
        The step (1..K), or None if the last estimate is outside the band.
    """
    est = np.atleast_2d(np.asarray(estimates, dtype=float))
    if est.shape[0] == 1 and np.ndim(estimates) == 1:
        est = est.T
    ref = np.asarray(reference, dtype=float).reshape(1, -1)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.max(np.abs(est - ref) / np.abs(ref), axis=1)
    inside = np.isfinite(rel) & (rel <= tol)
    if inside.size == 0 or not inside[-1]:
        return None
    outside = np.flatnonzero(~inside)
    return int(outside[-1] + 2) if outside.size else 1


def observations_used(step: int | None, obs_every: int) -> int | None:
    """Number of observations assimilated up to and including ``step``."""
    return None if step is None else step // obs_every

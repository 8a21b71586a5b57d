"""The calibration's fit: weighted ridge regression of the discrepancy.

:func:`fit` regresses a design's samples (:mod:`idbench.calibrate.design`)
on the features of the coarse observation and estimates the residual
covariance, in-sample or leave one scenario out (the maths:
:mod:`idbench.calibrate.discrepancy`); :func:`fit_discrepancy` simulates the
design and fits it, through the disk cache (:mod:`idbench.truth.cache`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from idbench.calibrate.design import CalibrationSettings, Design, Factory, Samples
from idbench.calibrate.discrepancy import FLOOR, Discrepancy, feature_matrix
from idbench.core.interfaces import FloatArray, ModelSpec, Prior
from idbench.core.scenario import Scenario
from idbench.truth.cache import cache_dir

log = logging.getLogger(__name__)


def _psd(a: FloatArray) -> FloatArray:
    """The nearest symmetric positive semi-definite matrix (eigenvalues clipped)."""
    w, v = np.linalg.eigh(0.5 * (a + a.T))
    return np.asarray((v * np.clip(w, 0, None)) @ v.T)


def _weighted_fit(
    phi: FloatArray, w: FloatArray, ridge: float
) -> FloatArray:
    """(Phi^T W Phi + ridge')^-1 (F, F), the intercept not penalised."""
    a = (phi * w[:, None]).T @ phi
    pen = ridge * float(np.mean(np.diag(a))) * np.eye(a.shape[0])
    pen[0, 0] = 0.0
    return np.asarray(np.linalg.pinv(a + pen, hermitian=True))


def fit(samples: Samples, settings: CalibrationSettings) -> Discrepancy:
    """Weighted ridge regression of the discrepancy on the coarse observation.

    The residual of a sample is modelled as N(0, C (t_i + t_0)), t_i =
    |z_i|^2 / z_s^2 (an error relative to the displacement, with a floor t_0
    = :data:`FLOOR`), so the weights are w_i = 1 / (t_i + t_0) and C is the
    weighted residual covariance. With two or more scenarios, C is the larger
    (by trace) of the in-sample one and that of the leave-one-scenario-out
    residuals where the others' fit interpolates (each scenario predicted by
    a fit on the others): how far the correction transfers to a path it did
    not see (``info["covariance"]`` says which; ``info["loso_rms"]`` is the
    RMS of every held-out residual, extrapolations included).
    """
    z = samples.z
    scale = float(np.sqrt(np.mean(np.sum(z**2, axis=1)))) or 1.0
    phi = feature_matrix(z, scale, settings.features)
    t = np.sum(z**2, axis=1) / scale**2
    w = 1.0 / (t + FLOOR)
    a_inv = _weighted_fit(phi, w, settings.ridge)
    pw = (phi * w[:, None]).T
    d_targets = samples.d_targets
    if d_targets is None:
        d_targets = np.zeros((len(z), 0))
    m, ng = samples.d_obs.shape[1], samples.d_grid.shape[1]
    y = np.hstack([samples.d_obs, samples.d_grid, d_targets])
    weights = a_inv @ (pw @ y)
    w_obs, w_grid, w_targets = weights[:, :m], weights[:, m:m + ng], weights[:, m + ng:]
    every = y - phi @ weights
    res = every[:, :m]
    dof = max(len(z) - phi.shape[1], 1)
    cov_unit = _psd((res * w[:, None]).T @ res / dof)
    blocks = _block_cov(every[:, m:], w, dof, samples.grid_dim, ng)
    leverage = np.einsum("ij,jk,ik->i", phi, a_inv, phi)
    info: dict[str, Any] = {
        "samples": len(z),
        "residual_rms": float(np.sqrt(np.mean(res**2))),
        "discrepancy_rms": float(np.sqrt(np.mean(samples.d_obs**2))),
        "covariance": "in-sample",
    }
    transfer = _transfer_residuals(phi, w, samples.group, y, m, settings.ridge)
    if transfer is not None:
        r_all, w_out, rms = transfer
        info["loso_rms"] = rms
        r_out = r_all[:, :m]
        if len(r_out) > phi.shape[1]:
            cov_out = _psd((r_out * w_out[:, None]).T @ r_out / len(r_out))
            if np.trace(cov_out) > np.trace(cov_unit):
                cov_unit, info["covariance"] = cov_out, "leave-one-scenario-out"
                blocks = _block_cov(r_all[:, m:], w_out, len(r_out),
                                    samples.grid_dim, ng)  # fmt: skip
    cov_grid, cov_targets = blocks
    return Discrepancy(settings.features, scale, w_obs, w_grid, cov_unit, a_inv,
                       FLOOR, float(leverage.max()), 0.0, info, w_targets,
                       cov_grid, cov_targets)  # fmt: skip


def _block_cov(
    res: FloatArray, w: FloatArray, dof: int, dim: int, ng: int
) -> tuple[FloatArray, FloatArray]:
    """Per-point weighted residual covariances of the grid (G, d, d) and targets.

    ``res`` (n, G d + 3 T): the grid's residuals, then the targets'.
    """
    n = len(res)
    grid = res[:, :ng].reshape(n, -1, dim)
    tgt = res[:, ng:].reshape(n, -1, 3)
    out = []
    for r in (grid, tgt):
        out.append(np.einsum("i,ipj,ipk->pjk", w, r, r) / dof)
    return out[0], out[1]


def _transfer_residuals(
    phi: FloatArray, w: FloatArray, group: FloatArray, y: FloatArray, m: int,
    ridge: float,
) -> tuple[FloatArray, FloatArray, float] | None:
    """Leave-one-scenario-out residuals where the others' fit interpolates.

    Each scenario is predicted by a fit on the others; its samples within
    that fit's largest training leverage (where the fit would not flag an
    extrapolation) give the residuals of every column of ``y`` and their
    weights. Also returns the RMS of every held-out residual of the first
    ``m`` columns (the markers). None with fewer than two scenarios.
    """
    groups = np.unique(group)
    if groups.size < 2:
        return None
    kept_r, kept_w, every = [], [], []
    for g in groups:
        out = group == g
        ai = _weighted_fit(phi[~out], w[~out], ridge)
        wg = ai @ ((phi[~out] * w[~out, None]).T @ y[~out])
        r = y[out] - phi[out] @ wg
        every.append(r[:, :m])
        lev_in = np.einsum("ij,jk,ik->i", phi[~out], ai, phi[~out]).max()
        lev_out = np.einsum("ij,jk,ik->i", phi[out], ai, phi[out])
        inside = lev_out <= lev_in
        kept_r.append(r[inside])
        kept_w.append(w[out][inside])
    rms = float(np.sqrt(np.mean(np.vstack(every) ** 2)))
    return np.vstack(kept_r), np.concatenate(kept_w), rms


def fit_discrepancy(
    factory: Factory,
    coarse: ModelSpec,
    fine_mesh: str,
    scenarios: Sequence[Scenario],
    prior: Prior,
    settings: CalibrationSettings | None = None,
    *,
    cache: bool = True,
) -> Discrepancy:
    """The approximation error of ``coarse`` against ``fine_mesh`` (cached on disk).

    Parameters
    ----------
    factory, coarse, fine_mesh, scenarios, prior
        What the calibration simulates (the fields of :class:`Design`).
    settings
        The design and the regression (default :class:`CalibrationSettings`).
    cache
        Read and write the cache (the fine paths are cached as truths anyway).
    """
    settings = settings or CalibrationSettings()
    if not scenarios:
        raise ValueError("a calibration needs at least one scenario")
    design = Design(factory, coarse, fine_mesh, tuple(scenarios), prior, settings)
    key = design.key()
    path = cache_dir() / f"discrepancy-{key}.npz"
    found = Discrepancy.load(path, key) if cache else None
    if found is not None:
        return found
    log.info("calibrating %s against %s on %s", coarse.mesh, fine_mesh,
             ", ".join(s.name for s in scenarios))  # fmt: skip
    samples, cost, scaled = design.samples()
    result = fit(samples, settings)
    info = {
        **result.info, "coarse": coarse.mesh, "fine": fine_mesh,
        "scenarios": [s.name for s in scenarios], "load_scaling": scaled,
    }  # fmt: skip
    result = replace(result, cost=cost, info=info)
    if cache:
        result.save(path, key)
    return result

"""The metrics of docs/design.md section 5, defined once and used everywhere.

Point estimates: shape error, settling step, observations used. Uncertainty:
interval coverage, NEES, CRPS of a Gaussian,
Wasserstein-1 to a gridded posterior, NIS of an innovation.
"""

from __future__ import annotations

import numpy as np
import scipy.integrate
import scipy.stats
from numpy.typing import ArrayLike

from idbench.core.interfaces import FloatArray
from idbench.estimate.lowrank import LowRankCovariance

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


# --- uncertainty ----------------------------------------------------------------


def _gaussian_args(
    mean: ArrayLike, std: ArrayLike, value: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    m, s, v = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (mean, std, value))
    try:
        m, s, v = np.broadcast_arrays(m, s, v)
    except ValueError as exc:
        raise ValueError(
            f"mean, std and value shapes differ: {m.shape}, {s.shape}, {v.shape}"
        ) from exc
    return m, s, v


def coverage(
    mean: ArrayLike, std: ArrayLike, value: ArrayLike, level: float
) -> FloatArray:
    r"""Whether ``value`` lies in the central Gaussian interval, per parameter.

    The interval of probability ``level`` of N(mean, std^2) is
    mean +- z std with z = Phi^-1((1 + level) / 2) (z = 0.994 for 0.68,
    1.960 for 0.95):

    .. math::

        c_j = \mathbb{1}\{|\theta_j - \mu_j| \le z \sigma_j\}.

    Parameters
    ----------
    mean, std
        The estimate and its standard deviation, shape (p,).
    value
        The value to cover (theta_true or the reference), shape (p,).
    level
        Probability of the interval, in (0, 1).

    Returns
    -------
    numpy.ndarray
        1.0 (covered) or 0.0 per parameter, NaN where mean, std or value is not
        finite or std < 0; averaged over seeds it is the empirical coverage.
    """
    if not (isinstance(level, int | float) and 0 < level < 1):
        raise ValueError(f"level = {level!r} is not allowed; use 0 < level < 1")
    m, s, v = _gaussian_args(mean, std, value)
    z = float(scipy.stats.norm.ppf(0.5 + level / 2))
    ok = np.isfinite(m) & np.isfinite(s) & np.isfinite(v) & (s >= 0)
    with np.errstate(invalid="ignore"):
        inside = (np.abs(v - m) <= z * s).astype(float)
    return np.where(ok, inside, np.nan)


def nees(mean: ArrayLike, std: ArrayLike, reference: ArrayLike) -> float:
    r"""Normalised estimation error squared with a diagonal covariance.

    .. math::

        \mathrm{NEES} = (\mu - \theta)^T P^{-1} (\mu - \theta)
        = \sum_j \left(\frac{\mu_j - \theta_j}{\sigma_j}\right)^2,
        \qquad P = \operatorname{diag}(\sigma^2),

    the squared z-score for p = 1. The estimators report a std per parameter
    only, so correlations are left out. For a calibrated Gaussian estimate its
    mean over runs is p (chi-squared with p degrees of freedom).

    Parameters
    ----------
    mean, std
        The estimate and its standard deviation, shape (p,).
    reference
        theta_true or the reference value, shape (p,).

    Returns
    -------
    float
        NEES; inf if some std is 0 and the error is not; NaN if anything is not
        finite or a std is negative.
    """
    m, s, v = _gaussian_args(mean, std, reference)
    if not (
        np.all(np.isfinite(m) & np.isfinite(s) & np.isfinite(v)) and np.all(s >= 0)
    ):
        return float("nan")
    err = m - v
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(err == 0, 0.0, (err / s) ** 2)
    return float(np.sum(terms))


def crps_gaussian(mean: ArrayLike, std: ArrayLike, value: ArrayLike) -> FloatArray:
    r"""Continuous ranked probability score of N(mean, std^2) at ``value``.

    Closed form (Gneiting & Raftery 2007), z = (theta - mu) / sigma:

    .. math::

        \mathrm{CRPS} = \int (F(x) - \mathbb{1}\{x \ge \theta\})^2 dx
        = \sigma \left[ z (2 \Phi(z) - 1) + 2 \varphi(z) - \frac{1}{\sqrt\pi}
        \right],

    and |theta - mu| for sigma = 0. Lower is better; it is in the parameter's
    units and rewards both accuracy and honest spread.

    Parameters
    ----------
    mean, std
        The estimate and its standard deviation, shape (p,).
    value
        The value scored against, shape (p,).

    Returns
    -------
    numpy.ndarray
        CRPS per parameter, shape (p,); NaN where an input is not finite or std
        is negative.
    """
    m, s, v = _gaussian_args(mean, std, value)
    ok = np.isfinite(m) & np.isfinite(s) & np.isfinite(v) & (s >= 0)
    pos = ok & (s > 0)
    out = np.where(ok & (s == 0), np.abs(v - m), np.nan)
    z = (v[pos] - m[pos]) / s[pos]
    norm = scipy.stats.norm
    out[pos] = s[pos] * (
        z * (2 * norm.cdf(z) - 1) + 2 * norm.pdf(z) - 1 / np.sqrt(np.pi)
    )
    return out


def wasserstein_to_grid(
    mean: float, std: float, grid: ArrayLike, density: ArrayLike
) -> float:
    r"""Wasserstein-1 distance between N(mean, std^2) and a gridded density (p = 1).

    .. math::

        W_1 = \int_{-\infty}^{\infty} |F_N(x) - F_G(x)| \, dx,

    F_G the cumulative trapezoid of ``density`` on ``grid`` (normalised to 1,
    0 left and 1 right of the grid, linear in between). The tails outside
    [a, b] = [grid[0], grid[-1]] are in closed form,
    int_{-inf}^a Phi((x - mu)/sigma) dx = (a - mu) Phi(z_a) + sigma phi(z_a) and
    int_b^inf (1 - Phi) dx = sigma phi(z_b) - (b - mu)(1 - Phi(z_b)); inside
    the grid, the trapezoid rule on the grid refined around the Gaussian. In
    the parameter's units: the distance from a point estimate to the
    posterior's mean when std = 0 and the posterior is a spike.

    Parameters
    ----------
    mean, std
        The Gaussian estimate (std >= 0; 0 is a point mass).
    grid
        Increasing abscissae, shape (G,), G >= 2.
    density
        Density (not necessarily normalised) at the grid points, shape (G,).

    Returns
    -------
    float
        W1, NaN if mean or std is not finite.
    """
    x = np.asarray(grid, dtype=float)
    f = np.asarray(density, dtype=float)
    if x.ndim != 1 or x.shape != f.shape or x.size < 2:
        raise ValueError(
            f"grid and density must be 1-D of equal length >= 2, got "
            f"{x.shape} and {f.shape}"
        )
    if np.any(np.diff(x) <= 0) or np.any(f < 0) or not np.all(np.isfinite(f)):
        raise ValueError("grid must increase and density be finite and >= 0")
    if not (np.isfinite(mean) and np.isfinite(std) and std >= 0):
        return float("nan")
    cdf = scipy.integrate.cumulative_trapezoid(f, x, initial=0.0)
    if cdf[-1] <= 0:
        raise ValueError("density integrates to 0 over the grid")
    cdf /= cdf[-1]
    a, b = x[0], x[-1]
    if std == 0:  # a point mass: int_{-inf}^mu F_G + int_mu^inf (1 - F_G)
        nodes = np.union1d(x, [min(max(mean, a), b)])
        fg = np.interp(nodes, x, cdf)
        lo, hi = nodes <= mean, nodes >= mean
        w = max(0.0, a - mean) + max(0.0, mean - b)
        if lo.sum() >= 2:
            w += scipy.integrate.trapezoid(fg[lo], nodes[lo])
        if hi.sum() >= 2:
            w += scipy.integrate.trapezoid(1 - fg[hi], nodes[hi])
        return float(w)
    norm = scipy.stats.norm
    za, zb = (a - mean) / std, (b - mean) / std
    left = (a - mean) * norm.cdf(za) + std * norm.pdf(za)
    right = std * norm.pdf(zb) - (b - mean) * norm.sf(zb)
    fine = mean + std * np.linspace(-8.0, 8.0, 2001)
    nodes = np.union1d(x, fine[(fine > a) & (fine < b)])
    diff = np.abs(norm.cdf((nodes - mean) / std) - np.interp(nodes, x, cdf))
    return float(left + right + scipy.integrate.trapezoid(diff, nodes))


def nis(innovation: ArrayLike, covariance: ArrayLike) -> float:
    r"""Normalised innovation squared of one observed step.

    .. math::

        \mathrm{NIS} = \nu^T S^{-1} \nu, \qquad \nu = y - \hat y, \quad
        S = H P H^T + R,

    chi-squared with m degrees of freedom for a consistent filter.

    Parameters
    ----------
    innovation
        nu, shape (m,).
    covariance
        S, shape (m, m) (or (m,) for a diagonal S), or a
        :class:`~idbench.estimate.lowrank.LowRankCovariance` (diagonal plus low rank).

    Returns
    -------
    float
        NIS; NaN if an input is not finite or S is singular.
    """
    v = np.atleast_1d(np.asarray(innovation, dtype=float))
    if isinstance(covariance, LowRankCovariance):  # diagonal + low rank: Woodbury
        if covariance.shape != (v.size, v.size):
            raise ValueError(f"innovation {v.shape} and covariance differ")
        parts = (v, covariance.diag, covariance.factor)
        if not all(np.all(np.isfinite(a)) for a in parts):
            return float("nan")
        try:
            return float(v @ covariance.solve(v))
        except np.linalg.LinAlgError:
            return float("nan")
    S = np.asarray(covariance, dtype=float)
    if S.ndim == 1:
        S = np.diag(S)
    if S.shape != (v.size, v.size):
        raise ValueError(f"innovation {v.shape} and covariance {S.shape} differ")
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(S))):
        return float("nan")
    try:
        return float(v @ np.linalg.solve(S, v))
    except np.linalg.LinAlgError:
        return float("nan")


NIS_LEVEL = 0.95
"""Probability of the two-sided chi-square band a run's summed NIS is tested against."""


def nis_band(dof: float, level: float = NIS_LEVEL) -> tuple[float, float]:
    r"""The two-sided ``level`` band of a chi-square with ``dof`` degrees of freedom.

    A consistent filter's innovations nu_k (m_k,) are independent with
    covariances S_k, so its NIS summed over the observed steps,

    .. math::

        \sum_k \nu_k^T S_k^{-1} \nu_k \sim \chi^2_{\sum_k m_k},

    (exactly for a linear-Gaussian model whose truth is drawn from the prior)
    lies in this band with probability ``level``; a sum above it says the
    filter's spread is too small for its data, below it too large.

    Returns
    -------
    tuple of float
        The ``(1 - level) / 2`` and ``(1 + level) / 2`` quantiles (NaN for
        ``dof`` < 1).
    """
    if not dof >= 1:
        return float("nan"), float("nan")
    tail = (1.0 - level) / 2.0
    chi2 = scipy.stats.chi2(dof)
    return float(chi2.ppf(tail)), float(chi2.ppf(1.0 - tail))


INCONSISTENT = "inconsistent"
"""The word that flags a run whose NIS lies outside its band (``warning``)."""


def inconsistency(total: float, dof: float) -> str:
    """Why a run is inconsistent with its data ('' if it is not, or cannot say).

    Its summed NIS ``total`` outside the two-sided 95% chi-square band of
    ``dof`` degrees of freedom (:func:`nis_band`).
    """
    lo, hi = nis_band(dof)
    if not (np.isfinite(total) and np.isfinite(lo)) or lo <= total <= hi:
        return ""
    side = ("above", "too small") if total > hi else ("below", "too large")
    return (
        f"{INCONSISTENT}: its NIS lies {side[0]} the 95% chi-square band of its "
        f"degrees of freedom (columns nis, nis_dof): its spread is {side[1]} for "
        "its data, its interval not to be believed"
    )


TARGET_LEVEL = 0.95
"""Probability mass of the target-covariance region a TRE coverage tests."""


def target_registration_error(predicted: ArrayLike, true: ArrayLike) -> FloatArray:
    """Distance (T,) between each target's predicted and true position.

    Both are displacements of the same undeformed target points (T, 3), so
    each distance is the norm of their difference (the model's length unit;
    the tables hold it in mm: ``tre_mm``).
    """
    a = np.asarray(predicted, dtype=float).reshape(-1, 3)
    b = np.asarray(true, dtype=float).reshape(-1, 3)
    if a.shape != b.shape:
        raise ValueError(f"target shapes differ: {a.shape} vs {b.shape}")
    return np.asarray(np.linalg.norm(a - b, axis=1))


def ellipsoid_covers(
    error: ArrayLike, covariance: ArrayLike, level: float = TARGET_LEVEL
) -> float:
    r"""Whether ``error`` (3,) lies in the ``level`` region of N(0, covariance).

    The region is the ellipsoid :math:`e^T C^{-1} e \le \chi^2_3(\text{level})`
    (7.81 for 95%). A degenerate C (fewer independent directions than 3, e.g.
    one parameter moving a target along a curve) is a flat region: only an
    error in C's range can lie in it, so the part of ``error`` outside that
    range must be below 1e-9 of the error's size (else: not covered).

    Returns
    -------
    float
        1.0 (covered), 0.0 (not), NaN if anything is not finite.
    """
    e = np.asarray(error, dtype=float).ravel()
    c = np.asarray(covariance, dtype=float).reshape(e.size, e.size)
    if not (np.all(np.isfinite(e)) and np.all(np.isfinite(c))):
        return float("nan")
    bound = float(scipy.stats.chi2.ppf(level, e.size))
    w, v = np.linalg.eigh(0.5 * (c + c.T))
    z = v.T @ e
    keep = w > 1e-12 * max(float(w.max(initial=0.0)), 0.0)
    outside = float(np.linalg.norm(z[~keep]))
    if outside > 1e-9 * max(float(np.linalg.norm(e)), 1e-300):
        return 0.0
    return float(np.sum(z[keep] ** 2 / w[keep]) <= bound)

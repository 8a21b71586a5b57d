"""Convergence diagnostics of MCMC chains: split R-hat, autocorrelation time.

The integrated autocorrelation time is emcee's
(:func:`emcee.autocorr.integrated_time`: the autocorrelation averaged over
chains, summed up to Sokal's window M >= c tau(M), c = 5). Split R-hat is the
classic one of Gelman et al. (2013, BDA3 section 11.4), the value of ArviZ's
``rhat(method="split")``; ArviZ is not a dependency (xarray and more for
twelve lines), the tests compare with it where it is installed.
"""

from __future__ import annotations

import numpy as np
from emcee.autocorr import integrated_time

from idbench.core.interfaces import FloatArray


def split_rhat(chains: FloatArray) -> FloatArray:
    """Split R-hat per parameter of chains (c, n, p); inf where a half is constant.

    Each chain is cut in halves (an odd middle draw dropped, as ArviZ and Stan
    do); with m draws per half, W the mean within-half variance and B / m the
    variance of the half means, R-hat = sqrt(((m - 1) / m W + B / m) / W).
    """
    half = chains.shape[1] // 2
    split = np.concatenate([chains[:, :half], chains[:, -half:]], axis=0)
    m = split.shape[1]
    means = split.mean(axis=1)  # (2c, p)
    within = split.var(axis=1, ddof=1).mean(axis=0)
    between = m * means.var(axis=0, ddof=1)
    var = (m - 1) / m * within + between / m
    with np.errstate(divide="ignore", invalid="ignore"):
        rhat = np.sqrt(var / within)
    return np.where(within > 0, rhat, np.inf)


def autocorr_time(chains: FloatArray, c: float = 5.0) -> FloatArray:
    """Integrated autocorrelation time (p,) of chains (c, n, p), emcee's estimate.

    A parameter on which some chain never moved gets inf (the estimate is
    undefined there, and such a chain has not mixed).
    """
    stuck = np.any(np.ptp(chains, axis=1) == 0, axis=0)  # (p,)
    tau = np.full(chains.shape[2], np.inf)
    if not stuck.all():
        moving = np.transpose(chains[:, :, ~stuck], (1, 0, 2))  # (n, chains, p')
        # tol = 0: the caller compares the chain length with tau itself
        tau[~stuck] = integrated_time(moving, c=c, tol=0)
    return tau


def acceptance(chains: FloatArray) -> float:
    """Fraction of kept iterations where a chain moved."""
    moved = np.any(np.diff(chains, axis=1) != 0, axis=2)
    return float(moved.mean())

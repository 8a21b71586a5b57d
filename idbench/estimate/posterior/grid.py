"""The posterior of one parameter (p = 1) by quadrature on a zooming grid in xi.

A zooming search finds where the log density is within ``tail`` of its maximum
(the posterior can be far narrower than the prior), then a final grid of
``points`` covers that region: the trapezoid rule for the moments, the
cumulative trapezoid for the quantiles (inverted exactly).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import scipy.integrate

from idbench.core.interfaces import FloatArray, ForwardModel, Observation, Prior
from idbench.estimate.posterior.result import LEVELS, Posterior
from idbench.estimate.posterior.settings import PosteriorSettings
from idbench.estimate.posterior.target import LogPosterior


def grid_posterior(
    model: ForwardModel,
    prior: Prior,
    observations: Sequence[Observation | None],
    settings: PosteriorSettings | None = None,
) -> Posterior:
    """The posterior of a single parameter (p = 1) by quadrature on a grid in xi.

    Search: a grid of ``zoom_points`` over mu +- span sd (within the bounds);
    keep the points within ``tail`` of the maximum and one neighbour each side;
    zoom into them until they hold at least 8 points (at most 20 zooms), then a
    final grid of ``points`` over that range. ``converged`` is False when the
    final grid's ends are within ``tail / 2`` of the maximum at a search edge
    that is not a model bound (mass cut off), or fewer than 5 of its points lie
    within 5 of the maximum (not resolved).
    """
    settings = settings or PosteriorSettings()
    if model.parameters.p != 1:
        raise ValueError(
            f"a grid posterior needs p = 1, the model has p = {model.parameters.p}"
        )
    target = LogPosterior(model, prior, observations, settings)
    need = target.cost(settings.zoom_points + settings.points)
    if need > settings.max_solves:
        raise ValueError(
            f"max_solves = {settings.max_solves} cannot hold one search grid and "
            f"the final grid ({need} solves)"
        )
    cost0 = model.cost()
    sd = math.sqrt(float(target.var[0]))
    blo, bhi = (float(b[0]) for b in target.xi_bounds())
    mu = float(target.mu[0])
    lo0, hi0 = mu - settings.span * sd, mu + settings.span * sd
    at_lower, at_upper = lo0 <= blo, hi0 >= bhi  # a model bound truncates
    if at_lower:
        lo0 = blo + 1e-9 * max(1.0, abs(blo))  # the bounds are open
    if at_upper:
        hi0 = bhi - 1e-9 * max(1.0, abs(bhi))
    lo, hi = lo0, hi0
    zooms = 0
    while True:
        xs = np.linspace(lo, hi, settings.zoom_points)
        lp = target(xs[:, None])
        if not np.any(np.isfinite(lp)):
            raise ValueError(
                "the model could not be solved anywhere on theta in "
                f"{target.theta(np.array([lo, hi]))}"
            )
        region = np.flatnonzero(lp > lp.max() - settings.tail)
        j0, j1 = max(region[0] - 1, 0), min(region[-1] + 1, xs.size - 1)
        lo, hi = float(xs[j0]), float(xs[j1])
        if region.size >= 8 or zooms >= 20:
            break
        zooms += 1
    xs = np.linspace(lo, hi, settings.points)
    lp = target(xs[:, None])
    top = float(lp.max())
    w = np.exp(lp - top)
    z = scipy.integrate.trapezoid(w, xs)
    pdf_xi = w / z
    theta = target.theta(xs)
    mean = scipy.integrate.trapezoid(theta * pdf_xi, xs)
    var = scipy.integrate.trapezoid((theta - mean) ** 2 * pdf_xi, xs)
    q_xi = _quantiles(xs, pdf_xi, LEVELS)
    dens = pdf_xi / target.transform.dtheta_dxi(xs)  # the density of theta
    mode = _parabolic_peak(theta, dens)
    edge_drop = top - max(float(lp[0]), float(lp[-1]))
    half = top - settings.tail / 2
    cut = (lo <= lo0 and lp[0] > half and not at_lower) or (
        hi >= hi0 and lp[-1] > half and not at_upper
    )
    resolved = np.sum(lp > top - 5.0) >= 5
    return Posterior(
        names=tuple(model.parameters.names),
        method="grid",
        mean=np.array([mean]),
        std=np.array([math.sqrt(max(var, 0.0))]),
        quantiles=target.theta(q_xi)[:, None],
        levels=LEVELS,
        map=np.array([mode]),
        converged=bool(resolved and not cut),
        n_solves=(model.cost() - cost0).forward_solves,
        grid=theta,
        density=dens,
        diagnostics={
            "edge_drop": edge_drop,
            "zooms": float(zooms),
            "failed": float(target.failed),
        },
    )


def _quantiles(x: FloatArray, f: FloatArray, levels: Sequence[float]) -> FloatArray:
    """Quantiles of the piecewise-linear density f on x (normalised here).

    In the interval [x_i, x_i + h] the cumulative is F_i + f_i t + (f_{i+1} -
    f_i) t^2 / (2h), inverted exactly (the cumulative trapezoid's own model).
    """
    cdf = scipy.integrate.cumulative_trapezoid(f, x, initial=0.0)
    total = cdf[-1]
    out = np.empty(len(levels))
    for j, q in enumerate(levels):
        target = q * total
        i = int(np.clip(np.searchsorted(cdf, target) - 1, 0, x.size - 2))
        h = x[i + 1] - x[i]
        a, b, c = (f[i + 1] - f[i]) / (2 * h), f[i], cdf[i] - target
        den = b + math.sqrt(max(b * b - 4 * a * c, 0.0))  # the stable root
        t = -2 * c / den if den > 0 else 0.0
        out[j] = x[i] + min(max(t, 0.0), h)
    return out


def _parabolic_peak(x: FloatArray, f: FloatArray) -> float:
    """Abscissa of the vertex of the parabola through the largest f and neighbours."""
    i = int(np.argmax(f))
    if i == 0 or i == x.size - 1:
        return float(x[i])
    xs, fs = x[i - 1 : i + 2], f[i - 1 : i + 2]
    a, b, _ = np.polyfit(xs - x[i], fs / fs[1], 2)
    return float(x[i] - b / (2 * a)) if a < 0 else float(x[i])

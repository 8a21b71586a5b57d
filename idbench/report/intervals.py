"""How sure a mean over seeds is: 95% intervals, and the seeds a precision needs.

Every mean in the summary, the report and the figures gets its interval from
:func:`interval`, which picks the method by the metric (:func:`method`):

- ``t``: Student's t interval of the mean, ``mean +- t(0.975, n-1) s / sqrt(n)``
  (:func:`scipy.stats.t`), for metrics that are close to normal over seeds:
  identified values and their ratios, reference values, shape errors, wall
  time, W1 distances;
- ``bootstrap``: percentile bootstrap of the mean (:data:`RESAMPLES` resamples
  drawn by a ``numpy.random.Generator`` seeded with :data:`SEED`, so a report
  is reproducible) for skewed or discrete metrics: settling steps, forward
  solves, NEES;
- ``binomial``: the exact (Clopper-Pearson) interval of a share, for the
  coverage columns (each run covers the value or not).

With fewer than two values there is no interval (NaN bounds). A paired
difference of coverage indicators is not a share, so :func:`interval` is
called with ``paired=True`` there and bootstraps it.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from scipy import stats

LEVEL = 0.95
"""Confidence level of every interval."""

RESAMPLES = 4000
"""Bootstrap resamples per interval."""

SEED = 29
"""Seed of the bootstrap's generator (one fresh generator per interval)."""

BOOTSTRAP = ("settling_step", "settling_obs", "n_solves", "nees_true", "nees_ref")
"""Skewed or discrete metrics: bootstrap percentile intervals."""


def method(metric: str) -> str:
    """The interval method of a summary metric: ``t``, ``bootstrap``, ``binomial``.

    Examples
    --------
    >>> method("E_final"), method("settling_step"), method("E_cover95_true")
    ('t', 'bootstrap', 'binomial')
    """
    if "_cover" in metric:
        return "binomial"
    if metric in BOOTSTRAP:
        return "bootstrap"
    return "t"


def interval(
    values: Iterable[float], metric: str = "", *, paired: bool = False
) -> tuple[float, float, float]:
    """Mean and 95% interval of ``values`` (NaN left out), by the metric's method.

    Parameters
    ----------
    values
        One value per seed (or per pair of runs).
    metric
        A summary column name (``E_final``, ``settling_step``...): chooses the
        method (:func:`method`); ``""`` is a t interval.
    paired
        The values are paired differences: a share's method becomes the
        bootstrap.

    Returns
    -------
    tuple of float
        ``(mean, lo, hi)``; the bounds are NaN with fewer than two values,
        the mean is NaN with none.
    """
    x = np.asarray(list(values), dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return math.nan, math.nan, math.nan
    mean = float(x.mean())
    if x.size < 2:
        return mean, math.nan, math.nan
    how = method(metric)
    if how == "binomial" and (paired or not np.isin(x, (0.0, 1.0)).all()):
        how = "bootstrap"
    if how == "binomial":
        ci = stats.binomtest(int(x.sum()), int(x.size)).proportion_ci(LEVEL, "exact")
        return mean, float(ci.low), float(ci.high)
    if how == "bootstrap":
        return (mean, *bootstrap_interval(x))
    return (mean, *t_interval(x))


def t_interval(x: np.ndarray, level: float = LEVEL) -> tuple[float, float]:
    """Student's t interval of the mean of ``x`` (n >= 2); zero width if constant."""
    n = x.size
    mean, s = float(x.mean()), float(x.std(ddof=1))
    if s == 0.0:
        return mean, mean
    lo, hi = stats.t.interval(level, n - 1, loc=mean, scale=s / math.sqrt(n))
    return float(lo), float(hi)


def bootstrap_interval(
    x: np.ndarray, level: float = LEVEL, resamples: int = RESAMPLES, seed: int = SEED
) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of ``x`` (seeded, reproducible).

    ``resamples`` samples of size n are drawn with replacement by
    ``numpy.random.default_rng(seed)``; the bounds are the (1 - level)/2 and
    (1 + level)/2 quantiles of their means.
    """
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, x.size, size=(resamples, x.size))
    means = x[idx].mean(axis=1)
    alpha = (1.0 - level) / 2.0
    lo, hi = np.quantile(means, [alpha, 1.0 - alpha])
    return float(lo), float(hi)


def excludes_zero(lo: float, hi: float) -> bool:
    """Whether an interval lies wholly on one side of 0 (NaN bounds: no)."""
    return bool(np.isfinite(lo) and np.isfinite(hi) and (lo > 0.0 or hi < 0.0))


def seeds_needed(s: float, half_width: float, level: float = LEVEL) -> int:
    """Seeds n for a t interval of half-width ``half_width`` at spread ``s``.

    The smallest n >= 2 with ``t(level, n-1) s / sqrt(n) <= half_width``,
    i.e. n ~ (t s / half_width)^2, from the seed-to-seed standard deviation
    ``s`` observed so far. 2 if ``s`` is 0.

    Examples
    --------
    >>> seeds_needed(10.0, 1.96 * 10.0 / 10.0)  # ~ (1.96 s / h)^2 = 100, t > z
    103
    """
    if not (np.isfinite(s) and np.isfinite(half_width) and half_width > 0):
        raise ValueError(
            f"need a finite spread and a positive half-width, not {s}, {half_width}"
        )
    z = stats.norm.ppf(0.5 + level / 2.0)
    n = max(2, math.ceil((z * s / half_width) ** 2))
    while stats.t.ppf(0.5 + level / 2.0, n - 1) * s / math.sqrt(n) > half_width:
        n += 1
    return n


def half_text(lo: float, hi: float) -> str:
    """A half-width or bound for people: 2 significant digits, whole if >= 100."""
    return _two_digits(max(hi - lo, 0.0) / 2.0)


def _two_digits(x: float) -> str:
    """``x`` to two significant digits (whole numbers from 100; ``-`` if not finite)."""
    if not np.isfinite(x):
        return "-"
    if abs(x) >= 100:
        return f"{x:.0f}"
    return f"{x:.2g}"


def format_interval(
    mean: float, lo: float, hi: float, metric: str, value: str
) -> str:
    """A mean with its interval, compactly: ``3257 +- 4`` or ``6 [4, 8]``.

    Symmetric (t) intervals show their half-width, the others their bounds;
    ``value`` is the mean as already formatted. Without bounds: ``value``.
    """
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return value
    if method(metric) == "t":
        return f"{value} +- {half_text(lo, hi)}"
    return f"{value} [{_bound(lo)}, {_bound(hi)}]"


def _bound(x: float) -> str:
    """A bootstrap or binomial bound: up to 3 significant digits."""
    if abs(x) >= 1000 or x == round(x):
        return f"{x:.0f}"
    return f"{x:.3g}"

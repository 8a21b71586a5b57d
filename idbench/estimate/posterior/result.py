"""The reference posterior's result: moments, quantiles and how it was found."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from idbench.core.interfaces import FloatArray

LEVELS = (0.025, 0.16, 0.5, 0.84, 0.975)
"""Probabilities of the reported quantiles (95% and 68% central intervals)."""


@dataclass(frozen=True)
class Posterior:
    """A reference posterior in natural units.

    Attributes
    ----------
    names
        Parameter names (the model's).
    method
        ``"grid"`` or ``"mcmc"``.
    mean, std
        Posterior mean and standard deviation, shape (p,).
    quantiles
        Shape (len(levels), p): the quantiles at ``levels``.
    levels
        Probabilities of the quantiles (default :data:`LEVELS`).
    map
        Shape (p,): grid: the mode of the density of theta (a parabola through
        the largest grid value and its neighbours);
        MCMC: the maximiser of the density of xi (found by least squares).
    converged
        False when the grid is cut off by its search range while mass remains,
        or when the MCMC diagnostics fail: then do not use it as a reference.
    n_solves
        Forward solves spent (from the model's cost, retries included).
    grid, density
        p = 1 grid only: theta grid (G,) and the normalised density of theta on
        it (integrates to 1 in theta).
    samples
        MCMC only: pooled draws (chains * samples, p) of theta.
    diagnostics
        Method details (grid: ``edge_drop``, ``zooms``, ``failed``; MCMC:
        ``rhat_max``, ``tau_max``, ``ess_min``, ``acceptance``).
    """

    names: tuple[str, ...]
    method: str
    mean: FloatArray
    std: FloatArray
    quantiles: FloatArray
    levels: tuple[float, ...]
    map: FloatArray
    converged: bool
    n_solves: int
    grid: FloatArray | None = None
    density: FloatArray | None = None
    samples: FloatArray | None = None
    diagnostics: dict[str, float] = field(default_factory=dict)

    def quantile(self, level: float) -> FloatArray:
        """The quantile (p,) at one of :attr:`levels`."""
        if level not in self.levels:
            raise ValueError(f"level = {level!r} is not one of {self.levels}")
        return np.asarray(self.quantiles[self.levels.index(level)])

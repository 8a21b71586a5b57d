"""How a reference posterior is computed: its settings and their budget.

:class:`PosteriorSettings` checks every value; :func:`minimum_solves` and
:func:`check_budget` say up front whether ``max_solves`` can hold the method
(a sweep checks them before it simulates anything).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from idbench.estimate.transforms import TRANSFORMS as _TRANSFORMS

TRANSFORMS = tuple(_TRANSFORMS)
"""Allowed ``transform`` values (the core's :mod:`idbench.estimate.transforms`)."""
METHODS = ("auto", "grid", "mcmc")
MAP_PATHS_PER_PARAMETER = 30
"""The MAP search of the MCMC method spends at most 30 (p + 1) paths."""


@dataclass(frozen=True)
class PosteriorSettings:
    """How to compute a reference posterior; every value is checked.

    Attributes
    ----------
    transform
        ``"log"`` (default) or ``"identity"``, as the filters' setting.
    sigma_floor
        Lower bound on the noise std in R, as the filters' setting.
    method
        ``"auto"`` (grid for p = 1, MCMC otherwise), ``"grid"`` or ``"mcmc"``.
    points
        Points of the final grid (p = 1), >= 21.
    zoom_points
        Points of each zooming search grid, >= 11.
    span
        Half-width of the first search grid in prior standard deviations of xi
        (clipped to the model's bounds).
    tail
        Drop of the log density below its maximum that counts as no mass.
    max_solves
        Budget of forward solves (paths times steps simulated).
    chains, warmup, samples
        MCMC chains (>= 2), warm-up and kept iterations per chain.
    seed
        Seed of the MCMC :class:`numpy.random.Generator`.
    rhat_max
        Largest split R-hat accepted as converged.
    tau_factor
        A chain must be longer than ``tau_factor`` autocorrelation times.
    """

    transform: str = "log"
    sigma_floor: float = 1e-6
    method: str = "auto"
    points: int = 201
    zoom_points: int = 41
    span: float = 6.0
    tail: float = 25.0
    max_solves: int = 50_000
    chains: int = 4
    warmup: int = 500
    samples: int = 1000
    seed: int = 0
    rhat_max: float = 1.05
    tau_factor: float = 50.0

    def __post_init__(self) -> None:
        for name, allowed in (("transform", TRANSFORMS), ("method", METHODS)):
            if getattr(self, name) not in allowed:
                raise ValueError(
                    f"{name} = {getattr(self, name)!r} is not allowed; use one of "
                    + ", ".join(repr(a) for a in allowed)
                )
        for name, low in (
            ("points", 21),
            ("zoom_points", 11),
            ("max_solves", 1),
            ("chains", 2),
            ("warmup", 0),
            ("samples", 10),
            ("seed", 0),
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise ValueError(
                    f"{name} = {v!r} is not allowed; it must be an integer >= {low}"
                )
        for name in ("sigma_floor", "span", "tail", "tau_factor"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(
                    f"{name} = {v!r} is not allowed; it must be finite > 0"
                )
        r = self.rhat_max
        if not (isinstance(r, int | float) and math.isfinite(r) and r > 1):
            raise ValueError(f"rhat_max = {r!r} is not allowed; it must be finite > 1")

    def method_for(self, p: int) -> str:
        """``"grid"`` or ``"mcmc"`` for p parameters (``"auto"`` resolved)."""
        if self.method != "auto":
            return self.method
        return "grid" if p == 1 else "mcmc"


def minimum_solves(settings: PosteriorSettings, p: int, n_steps: int) -> int:
    """Forward solves the method needs at least on a path observed at step K.

    Grid (p = 1): one search grid and the final grid; MCMC: the MAP search and
    the chains. :func:`~idbench.estimate.posterior.grid_posterior` and
    :func:`~idbench.estimate.posterior.mcmc_posterior` refuse a ``max_solves`` below it
    before solving anything.
    """
    if settings.method_for(p) == "grid":
        paths = settings.zoom_points + settings.points
    else:
        paths = MAP_PATHS_PER_PARAMETER * (p + 1) + settings.chains * (
            settings.warmup + settings.samples
        )
    return paths * n_steps


def check_budget(settings: PosteriorSettings, p: int, n_steps: int) -> None:
    """Raise ValueError naming ``max_solves`` if it cannot hold the method."""
    need = minimum_solves(settings, p, n_steps)
    if need > settings.max_solves:
        raise ValueError(
            f"max_solves = {settings.max_solves} cannot hold the "
            f"{settings.method_for(p)} posterior of {p} parameter(s) on {n_steps} "
            f"steps: it needs at least {need} solves"
        )

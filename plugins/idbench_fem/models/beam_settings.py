"""The beam model's own settings, and its end-traction reading of a scenario."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from idbench import Scenario
from idbench_fem.models.solid_settings import check_solver_settings

PARAMETER_KINDS = ("E", "E_regions")
DEFAULT_E = 5000.0
"""Default true Young's modulus (Pa) of the beam (docs/design.md section 1)."""


@dataclass(frozen=True)
class BeamSettings:
    """Settings of the ``svk-beam`` model (``--model-option NAME=VALUE``).

    The true modulus is not a setting: it is a true value, ``--true E=5000``
    (or ``--E-true``); its default is :data:`DEFAULT_E` (times ``true_factors``
    for each ``E_region``).

    Attributes
    ----------
    nu
        Poisson's ratio, in (-1, 0.5).
    parameters
        What is identified: ``"E"`` (one modulus) or ``"E_regions"``.
    regions
        With ``E_regions``: equal slabs along x (default 2, or 1 with an inclusion).
    inclusion
        With ``E_regions``: a box (x0, x1, y0, y1, z0, z1) in m that is the last
        region.
    true_factors
        Default true value of each region's modulus as a multiple of ``E``.
    grid
        Shape-error grid points along x, y, z (the study's 4 x 4 x 20).
    rtol, atol, max_iterations
        Newton tolerance (relative to the step's external force), absolute
        floor, iteration limit (None: the model's defaults, 1e-8, 1e-12 x the
        end force, 25).
    sensitivity_refine
        Refine sensitivities with one step of iterative refinement (None: on).
    solver
        ``"pardiso"`` or ``"scipy"`` (None: ``$IDBENCH_SOLVER`` or the best
        installed).
    processes
        Processes that solve a batched step's sigma points (None: 1). With 2,
        a helper process takes half of the pairs a step cannot predict: 1.5x
        faster RO-UKF steps with 4 regions on an idle 2-core machine; leave it
        at 1 in sweeps with ``--jobs`` (their runs already fill the cores).
        Results equal those of one process to the Newton tolerance; not part
        of the run's identity.
    """

    nu: float = 0.45
    parameters: str = "E"
    regions: int | None = None
    inclusion: tuple[float, ...] | None = None
    true_factors: tuple[float, ...] | None = None
    grid: tuple[int, int, int] = (20, 4, 4)
    rtol: float | None = None
    atol: float | None = None
    max_iterations: int | None = None
    sensitivity_refine: bool | None = None
    solver: str | None = None
    processes: int | None = None

    EXECUTION: ClassVar[tuple[str, ...]] = ("processes",)
    """Settings that change where work runs, not results (left out of run ids)."""

    def __post_init__(self) -> None:
        if not _number(self.nu) or not -1.0 < self.nu < 0.5:
            raise ValueError(f"nu {self.nu!r}: must be a number in (-1, 0.5)")
        if self.parameters not in PARAMETER_KINDS:
            raise ValueError(
                f"parameters {self.parameters!r}: allowed: {', '.join(PARAMETER_KINDS)}"
            )
        grid = tuple(self.grid) if isinstance(self.grid, list | tuple) else ()
        if len(grid) != 3 or not all(_whole(g, 1) for g in grid):
            raise ValueError(f"grid {self.grid!r}: need three whole numbers >= 1")
        object.__setattr__(self, "grid", grid)
        for name in ("inclusion", "true_factors"):
            value = getattr(self, name)
            if value is None:
                continue
            if not isinstance(value, list | tuple) or not all(map(_number, value)):
                raise ValueError(f"{name} {value!r}: need a list of numbers")
            object.__setattr__(self, name, tuple(float(v) for v in value))
        if self.regions is not None and not _whole(self.regions, 1):
            raise ValueError(f"regions {self.regions!r}: need a whole number >= 1")
        check_solver_settings(self)

    def options(self) -> dict[str, Any]:
        """The optional settings that were given, as the model's options dict."""
        names = ("regions", "inclusion", "rtol", "atol", "max_iterations",
                 "sensitivity_refine", "solver", "true_factors",
                 "processes")  # fmt: skip
        return {n: getattr(self, n) for n in names if getattr(self, n) is not None}

    def identity(self) -> list[Any]:
        """What of these settings identifies the data (and seeds the noise).

        The layout ``[nu, parameters, options, grid]`` keeps noise draws, and so
        results, equal to those of idbench 0.1 (the true values come before it
        in the run's data key). ``processes`` changes where work runs, not the
        data, so it is left out.
        """
        options = [
            [k, v] for k, v in sorted(self.options().items()) if k != "processes"
        ]
        return [self.nu, self.parameters, options, list(self.grid)]

    def true_values(self, p: int) -> tuple[float, ...]:
        """Default true value of each of ``p`` parameters: DEFAULT_E x true_factors."""
        factors = np.ones(p) if self.true_factors is None else self.true_factors
        if len(factors) != p:
            raise ValueError(
                f"true_factors {self.true_factors!r}: need one factor per parameter "
                f"({p})"
            )
        return tuple(float(DEFAULT_E * f) for f in factors)


@dataclass(frozen=True)
class EndTraction:
    """A scenario read as a dead uniform traction on the beam's free end.

    The scenario's ``load`` is ``{"direction": [dx, dy, dz], "magnitude": Pa}``;
    at step k of K the traction is ``(k / K) * magnitude * direction``.
    """

    name: str
    direction: tuple[float, float, float]
    magnitude: float

    @classmethod
    def of(cls, scenario: Scenario | EndTraction) -> EndTraction:
        """Read ``scenario``'s load; ValueError naming what is wrong."""
        if isinstance(scenario, EndTraction):
            return scenario
        load = scenario.load
        try:
            d = np.asarray(load["direction"], dtype=float)
            magnitude = float(load["magnitude"])
        except (KeyError, TypeError, ValueError):
            raise ValueError(
                f"scenario {scenario.name!r}: the beam needs a load "
                "{'direction': [dx, dy, dz], 'magnitude': Pa}, got "
                f"{load!r}"
            ) from None
        if d.shape != (3,) or not np.isclose(np.linalg.norm(d), 1.0):
            raise ValueError(
                f"scenario {scenario.name!r}: direction must be a unit 3-vector"
            )
        if not magnitude > 0:
            raise ValueError(f"scenario {scenario.name!r}: magnitude must be > 0")
        return cls(scenario.name, (d[0], d[1], d[2]), magnitude)

    def traction(self, k: int, n_steps: int) -> NDArray[np.float64]:
        """Traction vector (3,) at step ``k`` of ``n_steps``."""
        return (k / n_steps) * self.magnitude * np.asarray(self.direction, dtype=float)


def end_traction(
    name: str,
    direction: Any,
    magnitude: float,
    transfer: str = "",
    description: str = "",
) -> Scenario:
    """A beam scenario: ``magnitude`` Pa along the unit vector ``direction``."""
    d = [float(v) for v in direction]
    return Scenario(name, {"direction": d, "magnitude": float(magnitude)}, transfer,
                    description)  # fmt: skip


def _number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _whole(x: Any, low: int) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and x >= low

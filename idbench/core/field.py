"""Parameters that are one field: a value per cell of a partition of the body.

A model whose parameters are the values of one quantity on
the cells of a partition of its domain says so with ``parameter_field``
(:class:`~idbench.core.optional.ParameterFieldModel`): where each cell is,
how big it is and which cells touch, so that an estimator can put a
smoothness prior on the field (:mod:`idbench.estimate.prior`) and localize
its updates by distance, and the scores can draw and measure the map
(:mod:`idbench.score.maps`). Nothing here names a physics: a cell is a part
of the domain, a parameter is a value on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True, eq=False)
class ParameterField:
    """The cells of a parameter field, and the two settings of its prior.

    Parameter j of the model is the field's value on cell j.

    Attributes
    ----------
    centroids
        (p, d): each cell's centroid in the undeformed domain (model length
        unit, m for the built-in models).
    volumes
        (p,): each cell's measure (volume in 3-D), > 0.
    edges
        (e, 2): the pairs (i, j), i < j, of cells that share a boundary.
    areas
        (e,): the measure of each shared boundary (area in 3-D), > 0.
    length
        The prior's correlation length rho (same unit as ``centroids``): the
        distance at which two cells' log-values are correlated about
        exp(-2) = 0.14 (see :mod:`idbench.estimate.prior`).
    std
        The prior's marginal standard deviation of each cell's log-value;
        None: the comparison's prior (its std converted to log, as the
        filters' log transform does).
    truth_inside
        (p,) or None: the fraction of each cell's volume inside the truth's
        inclusion(s), for scoring the map only (never an estimator's input).
    truth_centre
        (d,) or None: the truth inclusion's centroid, for scoring only.
    """

    centroids: FloatArray
    volumes: FloatArray
    edges: IntArray
    areas: FloatArray
    length: float
    std: float | None = None
    truth_inside: FloatArray | None = None
    truth_centre: FloatArray | None = None

    def __post_init__(self) -> None:
        c = np.asarray(self.centroids, dtype=float)
        p = len(c)
        if c.ndim != 2 or p < 1:
            raise ValueError(f"centroids have shape {c.shape}: need (p, d), p >= 1")
        v = np.asarray(self.volumes, dtype=float)
        if v.shape != (p,) or not np.all(v > 0):
            raise ValueError(f"volumes: need {p} numbers > 0, got shape {v.shape}")
        e = np.asarray(self.edges, dtype=np.int64).reshape(-1, 2)
        a = np.asarray(self.areas, dtype=float).reshape(-1)
        if len(a) != len(e) or (len(e) and (e.min() < 0 or e.max() >= p)):
            raise ValueError("edges must index cells and have one area each")
        if len(e) and not (np.all(e[:, 0] < e[:, 1]) and np.all(a > 0)):
            raise ValueError("edges need i < j and areas > 0")
        if not (math.isfinite(self.length) and self.length > 0):
            raise ValueError(f"length = {self.length!r}: need a number > 0")
        if self.std is not None and not (math.isfinite(self.std) and self.std > 0):
            raise ValueError(f"std = {self.std!r}: need a number > 0 (or None)")
        for name, value in (("centroids", c), ("volumes", v), ("edges", e),
                            ("areas", a)):  # fmt: skip
            object.__setattr__(self, name, value)

    @property
    def p(self) -> int:
        """Number of cells (parameters)."""
        return len(self.volumes)

    @property
    def dim(self) -> int:
        """Dimension d of the domain."""
        return int(self.centroids.shape[1])

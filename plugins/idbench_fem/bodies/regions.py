"""What theta is: one Young's modulus, or one per element region."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from idbench import ParameterSpec

E_BOUNDS = (1.0, 1e8)
"""Bounds (Pa) of every Young's modulus."""

KINDS = ("E", "E_regions")


def parameter_regions(
    kind: str,
    centroids: NDArray[np.float64],
    lower: NDArray[np.float64],
    upper: NDArray[np.float64],
    option: Any,
) -> tuple[ParameterSpec, NDArray[np.int64]]:
    """Return the parameter spec and the region index of every element.

    Parameters
    ----------
    kind
        ``"E"`` (one modulus, region 0 everywhere) or ``"E_regions"``.
    centroids
        Element centroids (T, 3); an element belongs to the region of its centroid.
    lower, upper
        Bounding box of the body.
    option
        ``spec.option``: ``regions`` (default 2) equal slabs along x, or
        ``inclusion`` = (x0, x1, y0, y1, z0, z1): that box is the last region
        and the rest is split into ``regions`` (default 1) equal slabs along x,
        so p = regions + 1 (default: region 0 the rest, region 1 the box).

    Returns
    -------
    spec, regions
        :class:`idbench.ParameterSpec` and region per element (T,).
    """
    lo, hi = E_BOUNDS
    if kind == "E":
        return ParameterSpec(("E",), (lo,), (hi,)), np.zeros(
            len(centroids), dtype=np.int64
        )
    if kind != "E_regions":
        raise ValueError(f"parameters {kind!r}: allowed are {', '.join(KINDS)}")
    inclusion = option("inclusion")
    slabs = option("regions", 2 if inclusion is None else 1)
    if not isinstance(slabs, int) or isinstance(slabs, bool) or slabs < 1:
        raise ValueError(f"regions = {slabs!r}: need an integer >= 1")
    t = (centroids[:, 0] - lower[0]) / (upper[0] - lower[0])
    regions = np.minimum((t * slabs).astype(np.int64), slabs - 1)
    p = slabs
    if inclusion is not None:
        box = np.asarray(inclusion, dtype=float)
        if box.shape != (6,) or np.any(box[1::2] <= box[0::2]):
            raise ValueError(
                f"inclusion {inclusion!r}: need (x0, x1, y0, y1, z0, z1), x0 < x1 etc."
            )
        inside = np.all((centroids >= box[0::2]) & (centroids <= box[1::2]), axis=1)
        if not inside.any() or inside.all():
            raise ValueError(
                f"inclusion {inclusion!r} contains no element or all of them"
            )
        regions[inside] = slabs
        p = slabs + 1
    if len(np.unique(regions)) != p:
        raise ValueError(f"regions = {slabs}: some slab contains no element; use fewer")
    names = tuple(f"E_region{r}" for r in range(p))
    return ParameterSpec(names, (lo,) * p, (hi,) * p), regions

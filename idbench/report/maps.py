"""The maps of field runs: what a report shows instead of hundreds of parameters.

A run whose parameters are a field (:class:`idbench.ParameterField`) has a
``field_cells`` column (:func:`idbench.score.maps.map_columns`: the cells'
centroids and the truth's inclusion fractions). :func:`map_figure` draws, for
one run of each (scenario, mesh, estimator, observation), the truth's and the
estimate's map in the slab through the truth's inclusion (else through the
body's middle) normal to its thinnest axis: each cell a dot at its centroid,
coloured by log10(theta / the map's median), the truth's inclusion cells
ringed. :func:`is_field` says when the report should draw maps and list the
map metrics rather than every parameter.
"""

from __future__ import annotations

from pathlib import PurePath
from typing import Any

import numpy as np
import pandas as pd

from idbench.score.maps import cells_of

LISTED = 8
"""Fields of more cells are summarised by their map metrics, not per cell."""
MAX_PANELS = 6
"""Runs drawn at most (the first seed of each group)."""


def _short(value: Any) -> str:
    """A mesh path's file stem; anything else as text."""
    text = str(value)
    return PurePath(text).stem if ("/" in text or "\\" in text) else text


def is_field(runs: pd.DataFrame, names: list[str]) -> bool:
    """Whether ``runs`` are of a field too large to list its parameters one by one."""
    if "field_cells" not in runs or not runs["field_cells"].notna().any():
        return False
    return len(names) > LISTED


def _values(row: pd.Series, names: list[str], suffix: str) -> np.ndarray:
    return np.array([row.get(f"{n}{suffix}", np.nan) for n in names], dtype=float)


def _slab(
    x: np.ndarray, inside: np.ndarray | None
) -> tuple[np.ndarray, tuple[int, int]]:
    """Cells in the slab through the inclusion, and the two in-plane axes."""
    span = np.ptp(x, axis=0)
    normal = int(np.argmin(span))
    plane = tuple(int(a) for a in np.argsort(span)[::-1][:2])
    if inside is not None and inside.sum() > 0:
        centre = (x * inside[:, None]).sum(axis=0) / inside.sum()
    else:
        centre = x.mean(axis=0)
    spacing = (np.prod(span) / len(x)) ** (1 / 3)
    keep = np.abs(x[:, normal] - centre[normal]) <= max(spacing, 1e-12)
    return keep, (plane[0], plane[1])


def map_figure(runs: pd.DataFrame, names: list[str]) -> Any:
    """Truth and estimate side by side, one row per drawn run (matplotlib)."""
    import matplotlib.pyplot as plt

    keys = [k for k in ("scenario", "mesh", "estimator", "observe") if k in runs]
    first = runs.sort_values("seed") if "seed" in runs else runs
    drawn = first.groupby(keys, sort=False).head(1).head(MAX_PANELS)
    x0, _ = cells_of(drawn["field_cells"].iloc[0])
    span = np.sort(np.ptp(x0, axis=0))[::-1]
    height = float(np.clip(3.6 * span[1] / max(span[0], 1e-12) + 1.0, 1.8, 3.6))
    fig, axs = plt.subplots(len(drawn), 2, figsize=(8.4, height * len(drawn)),
                            squeeze=False, layout="constrained")  # fmt: skip
    scatter = None
    for (_, row), (left, right) in zip(drawn.iterrows(), axs, strict=True):
        x, inside = cells_of(row["field_cells"])
        true, est = _values(row, names, "_true"), _values(row, names, "_final")
        keep, (a, b) = _slab(x, inside)
        ref = float(np.nanmedian(np.log10(true)))
        for ax, value, title in ((left, true, "truth (its cells)"),
                                 (right, est, row.get("estimator", ""))):  # fmt: skip
            v = np.log10(value[keep]) - ref
            scatter = ax.scatter(1000 * x[keep, a], 1000 * x[keep, b], c=v, s=40,
                                 cmap="RdBu_r", vmin=-0.6, vmax=0.6)  # fmt: skip
            if inside is not None:
                ring = keep & (inside > 0.5)
                ax.scatter(1000 * x[ring, a], 1000 * x[ring, b], s=90,
                           facecolors="none", edgecolors="k", linewidths=0.8)
            label = ", ".join(_short(row[k]) for k in keys if k != "estimator")
            ax.set_title(f"{title}: {label}", fontsize=8)
            ax.set_aspect("equal")
            ax.set_xlabel(f"axis {a} (mm)", fontsize=8)
            ax.set_ylabel(f"axis {b} (mm)", fontsize=8)
    if scatter is not None:
        bar = fig.colorbar(scatter, ax=axs.ravel().tolist(), shrink=0.6)
        bar.set_label("log10(E / truth's median)")
    return fig

"""Still images of the 3D view's scenes, for report.md and the docs' pages.

The best and the worst run of a comparison (:func:`idbench.report.scene.best_and_worst`)
at their last stored step, drawn as the interactive view draws them: the
model's surface coloured by its displacement error (mm, the same scale for
both), the truth's surface translucent, a depth camera's cloud with its
outliers, the markers (observed, predicted) and the hidden targets (true,
predicted, each one's predicted 95% region as a wireframe). Rendered with
matplotlib's mplot3d (Agg: no display, nothing to install beyond idbench's
own dependencies); triangles are sorted by depth per polygon, which suits
the convex bodies of the built-in models.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from idbench.report.figures import plain
from idbench.report.scene import (
    MM,
    RunScene,
    Scenes,
    best_and_worst,
    ellipsoid_axes,
    error_range,
)
from idbench.report.view3d import COLOURS, LEGEND

VIEW_FROM = (0.55, -0.75, 0.38)
"""The direction from the body to the camera (the interactive view's start)."""


def write_stills(root: Path, runs: pd.DataFrame, scenes: Scenes) -> list[Path]:
    """Write ``view_best.png`` and ``view_worst.png`` in ``root``; their paths.

    None without scenes (or with a ``problem``: nothing stale is drawn).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if scenes.problem:
        return []
    chosen = best_and_worst(runs, scenes)
    top = error_range(scenes, runs)
    written = []
    by_id = runs.set_index(runs["run_id"].astype(str))
    for label, run_id in chosen:
        fig = still(scenes.runs[run_id], by_id.loc[run_id], top, label)
        path = root / f"view_{label}.png"
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        written.append(path)
    return written


def still(scene: RunScene, row: Any, top: float, label: str = "") -> Any:
    """One run's scene at its last stored step as a matplotlib figure."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import LinearSegmentedColormap, Normalize
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    cmap = LinearSegmentedColormap.from_list("view", np.array(COLOURS) / 255.0)
    norm = Normalize(0.0, top)
    shown = scene.shown
    s = len(shown.steps) - 1
    vertices = shown.surface.vertices + shown.displacement[s]
    tri = shown.surface.triangles
    fig = plt.figure(figsize=(6.4, 4.8))
    ax = fig.add_subplot(projection="3d")
    ax.computed_zorder = False  # the points over the surface: targets lie inside
    if scene.error_mm is not None:
        face = np.nanmean(scene.error_mm[s][tri], axis=1)
        colours = cmap(norm(np.nan_to_num(face, nan=0.0)))
    else:
        colours = np.tile([0.6, 0.6, 0.6, 1.0], (len(tri), 1))
    ax.add_collection3d(Poly3DCollection(
        vertices[tri], facecolors=colours, edgecolors=(0, 0, 0, 0.15),
        linewidths=0.2,
    ))  # fmt: skip
    extent = [vertices]
    truth = scene.truth
    if truth is not None:
        j = np.flatnonzero(truth.steps == shown.steps[s])
        if j.size:
            moved = truth.surface.vertices + truth.displacement[j[0]]
            ax.add_collection3d(Poly3DCollection(
                moved[truth.surface.triangles], facecolors=(0.3, 0.3, 0.3, 0.06),
                edgecolors=(0.3, 0.3, 0.3, 0.05), linewidths=0.2,
            ))  # fmt: skip
            extent.append(moved)
    arrays = shown.arrays
    if "cloud_points" in arrays:
        points = np.asarray(arrays["cloud_points"][s], dtype=float)
        out = np.asarray(arrays["cloud_outliers"][s], dtype=bool)
        ax.scatter(*points[~out].T, s=2, c="#1a3399", depthshade=False)
        ax.scatter(*points[out].T, s=6, c="#d91a1a", depthshade=False)
    extent += _points(ax, arrays, s)
    _frame(ax, np.vstack(extent))
    if scene.error_mm is not None:
        bar = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
        fig.colorbar(bar, ax=ax, shrink=0.6, label="displacement error (mm)")
    error = row.get("shape_error_mean_final")
    scored = f", shape error {MM * float(error):.3g} mm" if _finite(error) else ""
    scored += " per grid point" if scored else ""
    ax.set_title(
        plain(f"{label}: {row.get('estimator')} on {row.get('mesh')}, seed "
              f"{row.get('seed')}{scored}; step {int(shown.steps[s])}"),
        fontsize=9,
    )  # fmt: skip
    return fig


def _points(ax: Any, arrays: Any, s: int) -> list[Any]:
    """The markers and the targets of stored step ``s``, the regions, a legend.

    Returns the positions drawn (to frame them).
    """
    sizes = {"markers-observed": 40, "markers-predicted": 14, "targets-true": 50,
             "targets-predicted": 18}  # fmt: skip
    drawn = []
    for key, colour, text in LEGEND:
        name = key.replace("-", "_")
        if name not in arrays:
            continue
        p = np.asarray(arrays[name][s], dtype=float).reshape(-1, 3)
        p = p[np.isfinite(p).all(axis=1)]
        ax.scatter(*p.T, s=sizes[key], c=colour, depthshade=False, label=text,
                   zorder=5)  # fmt: skip
        drawn.append(p)
    if "targets_cov" in arrays and s == len(arrays["steps"]) - 1:
        u, v = np.meshgrid(np.linspace(0, np.pi, 9), np.linspace(0, 2 * np.pi, 17))
        unit = np.stack([np.sin(u) * np.cos(v), np.sin(u) * np.sin(v), np.cos(u)])
        centres = np.asarray(arrays["targets_predicted"][s], dtype=float)
        for centre, axes in zip(centres, ellipsoid_axes(arrays["targets_cov"]),
                                strict=True):  # fmt: skip
            if np.all(np.isfinite(axes)) and np.all(np.isfinite(centre)):
                x = centre[:, None, None] + np.einsum("ij,jab->iab", axes, unit)
                ax.plot_wireframe(*x, color=LEGEND[-1][1], linewidth=0.4)
    if drawn:
        ax.legend(loc="lower left", fontsize=7, frameon=False)
    return drawn


def _frame(ax: Any, points: Any) -> None:
    """Equal axes around ``points``, seen from :data:`VIEW_FROM`."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    mid = (lo + hi) / 2
    half = np.maximum((hi - lo) / 2, 1e-3 * float((hi - lo).max()) + 1e-12)
    for setter, c, h in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid, half,
                            strict=True):  # fmt: skip
        setter(c - h, c + h)
    ax.set_box_aspect(tuple(half), zoom=1.2)
    x, y, z = VIEW_FROM
    ax.view_init(
        elev=math.degrees(math.asin(z / math.hypot(x, y, z))),
        azim=math.degrees(math.atan2(y, x)),
    )
    ax.set_axis_off()


def _finite(value: Any) -> bool:
    try:
        return bool(np.isfinite(float(value)))
    except (TypeError, ValueError):
        return False

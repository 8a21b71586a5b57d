r"""The scenes of a comparison: each run's surface against the truth's, read back.

A run's stored surfaces (:mod:`idbench.store.surfaces`) are read, checked and
set against the truth of its data set: the *displacement error* at each
vertex X of the model's surface is

.. math::

    e(X) = \lVert u_h(X) - u^*(P(X)) \rVert,

with u_h the model's displacement (as the run scored it), u* the truth's and
P(X) the closest point to X on the truth's undeformed surface (the truth's
displacement there interpolated linearly in its triangle). It is a picture of
where the shape is wrong, not the scored shape error (that one is measured at
the body's shape-error points: ``shape_error_mean_final``). With it, where the
run stored them, the markers (observed and predicted) and the hidden targets
(true and predicted, with each one's predicted 95% region at the last step:
the ellipsoid :math:`e^T C^{-1} e \le \chi^2_3(0.95)`, semi-axes
:data:`REGION` times the square roots of C's eigenvalues along its
eigenvectors, :func:`ellipsoid_axes`). Both the interactive view
(:mod:`idbench.report.view3d`) and the stills (:mod:`idbench.report.stills`)
draw these scenes.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import scipy.stats
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from idbench.core.interfaces import FloatArray
from idbench.observe.surface import closest_on_triangles
from idbench.score.metrics import TARGET_LEVEL
from idbench.store import surfaces

log = logging.getLogger(__name__)

MM = 1000.0
"""Model length unit (m) to the report's (mm)."""

CANDIDATES = 8
"""Triangles (nearest centroids) searched for each vertex's closest point."""

REGION = float(np.sqrt(scipy.stats.chi2.ppf(TARGET_LEVEL, 3)))
"""Radius of the 95% region of N(0, I) in three dimensions (2.7955): a
target's ellipsoid is it times the square roots of C's eigenvalues."""


@dataclass
class Surface:
    """An undeformed surface: vertices (V, 3) and triangles (T, 3)."""

    vertices: FloatArray
    triangles: NDArray[Any]
    mesh: str = ""


@dataclass
class Shown:
    """One data set's truth or one run, as stored: surface displacements per step.

    Attributes
    ----------
    surface
        Its undeformed surface.
    steps
        The stored load steps (S,).
    displacement
        (S, V, 3) displacements of the surface's vertices (model unit).
    """

    surface: Surface
    steps: NDArray[Any]
    displacement: FloatArray
    arrays: dict[str, Any] = field(default_factory=dict)


@dataclass
class RunScene:
    """A run's scene: its surface, its truth's, the error at each vertex (mm)."""

    run_id: str
    shown: Shown
    truth: Shown | None
    error_mm: FloatArray | None  # (S, V); None without a truth field


@dataclass
class Scenes:
    """Every run's scene that could be read, and why the others could not.

    ``problem`` is set when the folder fails its checks: a view then shows it
    instead of the scenes (they may be stale).
    """

    runs: dict[str, RunScene] = field(default_factory=dict)
    problem: str = ""
    missing: list[str] = field(default_factory=list)


def read_scenes(root: Path, runs: pd.DataFrame) -> Scenes:
    """The scenes of the runs of ``runs`` stored in ``root``'s surfaces folder.

    The folder is checked first (:func:`idbench.store.surfaces.check` against
    the manifest's ``inputs``): if it fails, ``problem`` says why and no scene
    is read. A run without a stored surface (a model without ``surface``, an
    older folder) is listed in ``missing``.
    """
    out = Scenes()
    if not surfaces.folder(root).is_dir() or "run_id" not in runs:
        out.missing = [str(r) for r in runs.get("run_id", [])]
        return out
    inputs = _inputs(root)
    out.problem = surfaces.check(root, inputs)
    if out.problem:
        return out
    meshes: dict[str, Surface] = {}
    truths: dict[str, Shown | None] = {}
    projections: dict[tuple[str, str], tuple[Any, Any]] = {}
    for run_id in map(str, runs["run_id"]):
        path = surfaces.folder(root) / f"run-{run_id}.npz"
        if not path.exists():
            out.missing.append(run_id)
            continue
        try:
            shown = _shown(root, surfaces.load(path), meshes)
            truth_key = str(shown.arrays.get("truth_key", ""))
            if truth_key and truth_key not in truths:
                truths[truth_key] = _truth(root, truth_key, meshes)
        except surfaces.SurfaceError as exc:
            out.problem = str(exc)
            out.runs.clear()
            return out
        truth = truths.get(truth_key) if truth_key else None
        error = None
        if truth is not None:
            pair = (str(shown.arrays["mesh_key"]), truth_key)
            if pair not in projections:
                projections[pair] = project(shown.surface, truth.surface)
            error = displacement_error(shown, truth, *projections[pair])
        out.runs[run_id] = RunScene(run_id, shown, truth, error)
    return out


def _inputs(root: Path) -> list[Any]:
    try:
        manifest = json.loads((root / "manifest.json").read_text())
    except (OSError, ValueError):
        return []
    inputs = manifest.get("inputs") if isinstance(manifest, dict) else None
    return inputs if isinstance(inputs, list) else []


def _mesh(root: Path, key: str, meshes: dict[str, Surface]) -> Surface:
    if key not in meshes:
        path = surfaces.folder(root) / f"mesh-{key}.npz"
        if not path.exists():
            raise surfaces.SurfaceError(f"{path} is missing")
        arrays = surfaces.load(path)
        meshes[key] = Surface(
            np.asarray(arrays["vertices"], dtype=float),
            np.asarray(arrays["triangles"], dtype=np.int64),
            str(arrays.get("mesh", "")),
        )
    return meshes[key]


def _shown(root: Path, arrays: dict[str, Any], meshes: dict[str, Surface]) -> Shown:
    surface = _mesh(root, str(arrays["mesh_key"]), meshes)
    moved = np.asarray(arrays["displacement"], dtype=float)
    steps = np.asarray(arrays["steps"], dtype=np.int64)
    if moved.shape != (len(steps), len(surface.vertices), 3):
        raise surfaces.SurfaceError(
            f"stored displacements of shape {moved.shape} do not fit their mesh "
            f"({len(surface.vertices)} vertices) and {len(steps)} steps"
        )
    for name in surfaces.POINTS:
        shape = np.shape(arrays.get(name, np.zeros((len(steps), 0, 3))))
        if len(shape) != 3 or shape[0] != len(steps) or shape[2] != 3:
            raise surfaces.SurfaceError(
                f"stored {name} of shape {shape} do not fit {len(steps)} steps"
            )
    if "targets_cov" in arrays:
        targets = np.shape(arrays.get("targets_true", ()))[1:2]
        if np.shape(arrays["targets_cov"]) != (*targets, 3, 3):
            raise surfaces.SurfaceError(
                f"stored targets_cov of shape {np.shape(arrays['targets_cov'])} "
                "does not fit its targets"
            )
    return Shown(surface, steps, moved, arrays)


def ellipsoid_axes(covariance: Any) -> FloatArray:
    """Each target's 95% region as a map of the unit sphere (T, 3, 3).

    Column j of ``out[t]`` is the region's semi-axis j: :data:`REGION`
    sqrt(lambda_j) v_j for the eigenpairs of C_t (negative round-off clipped
    to 0: a flat region); the points c + A x, |x| = 1, are its surface. NaN
    where C_t is not finite (no region).
    """
    cov = np.asarray(covariance, dtype=float).reshape(-1, 3, 3)
    out = np.full(cov.shape, np.nan)
    finite = np.isfinite(cov).all(axis=(1, 2))
    if finite.any():
        w, v = np.linalg.eigh(0.5 * (cov[finite] + cov[finite].transpose(0, 2, 1)))
        out[finite] = v * (REGION * np.sqrt(np.clip(w, 0.0, None)))[:, None, :]
    return out


def _truth(root: Path, key: str, meshes: dict[str, Surface]) -> Shown | None:
    path = surfaces.folder(root) / f"truth-{key}.npz"
    if not path.exists():
        return None
    return _shown(root, surfaces.load(path), meshes)


def project(model: Surface, truth: Surface) -> tuple[NDArray[Any], FloatArray]:
    """Closest point on ``truth`` of each vertex of ``model``.

    Returns
    -------
    corners, weights
        (V, 3) the truth vertices of the triangle holding it and (V, 3) its
        barycentric weights there.
    """
    tri = truth.triangles
    corners = truth.vertices[tri]  # (T, 3, 3)
    tree = cKDTree(corners.mean(axis=1))
    k = min(CANDIDATES, len(tri))
    _, near = tree.query(model.vertices, k=k)
    near = np.asarray(near).reshape(len(model.vertices), k)
    p = np.repeat(model.vertices, k, axis=0)
    cand = near.reshape(-1)
    closest, bary = closest_on_triangles(
        p, corners[cand, 0], corners[cand, 1], corners[cand, 2]
    )
    dist = np.linalg.norm(closest - p, axis=1).reshape(-1, k)
    best = np.argmin(dist, axis=1)
    rows = np.arange(len(model.vertices)) * k + best
    return tri[cand[rows]], bary[rows]


def displacement_error(
    shown: Shown, truth: Shown, corners: NDArray[Any], weights: FloatArray
) -> FloatArray:
    """The error e (S, V) in mm at the run's stored steps (NaN: no truth step)."""
    index = {int(k): i for i, k in enumerate(truth.steps)}
    out = np.full(shown.displacement.shape[:2], np.nan)
    for i, k in enumerate(shown.steps):
        j = index.get(int(k))
        if j is None:
            continue
        u_truth = np.einsum("vc,vcd->vd", weights, truth.displacement[j][corners])
        out[i] = MM * np.linalg.norm(shown.displacement[i] - u_truth, axis=1)
    return out


def best_and_worst(runs: pd.DataFrame, scenes: Scenes) -> list[tuple[str, str]]:
    """(label, run id) of the best and the worst run with a scene.

    By the scored shape error at the last step (``shape_error_mean_final``) among
    the ok runs; one entry if only one run qualifies, none without.
    """
    if "shape_error_mean_final" not in runs or "status" not in runs:
        return []
    ok = runs[(runs["status"] == "ok") & runs["run_id"].astype(str).isin(scenes.runs)]
    ok = ok[np.isfinite(ok["shape_error_mean_final"].astype(float))]
    if ok.empty:
        return []
    ranked = ok.sort_values("shape_error_mean_final", kind="stable")
    best, worst = str(ranked["run_id"].iloc[0]), str(ranked["run_id"].iloc[-1])
    return [("best", best)] if best == worst else [("best", best), ("worst", worst)]


def error_range(scenes: Scenes, runs: pd.DataFrame) -> float:
    """The colour scale's top (mm): the largest error of the ok runs (else all)."""
    status = runs["status"] if "status" in runs else pd.Series("ok", runs.index)
    ok = set(map(str, runs.loc[status == "ok", "run_id"]))
    values = [s.error_mm for r, s in scenes.runs.items() if s.error_mm is not None]
    chosen = [
        s.error_mm for r, s in scenes.runs.items()
        if s.error_mm is not None and r in ok
    ] or values  # fmt: skip
    finite = [v[np.isfinite(v)] for v in chosen]
    top = max((float(v.max()) for v in finite if v.size), default=0.0)
    return top if top > 0 else 1.0

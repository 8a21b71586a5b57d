"""report.html's interactive 3D view: the organ at each stored step, per run.

The page embeds, once: a subset of three.js (``assets/vendor/three.min.js``, MIT,
bundled from the npm package; see THIRD_PARTY.md) and the view's own script
(``assets/view3d.js``); and the scenes (:mod:`idbench.report.scene`) as one
JSON block of base64 arrays, compact:

- each surface once (float32 vertices, uint32 triangles);
- displacements as int16 with a scale per run (a step of the largest
  displacement / 32767: below a micrometre for a centimetre);
- the displacement error per vertex as uint8 on the common colour scale
  (0 to the largest error of the ok runs; 255: none);
- a cloud once per data set (uint16 in its bounding box), its outliers as bits;
- markers (observed, predicted) and targets (true, predicted) as float32
  positions per stored step (NaN: not observed), each target's 95% region
  at the last step as its centre and its semi-axes (a 3 x 3 map of the unit
  sphere, :func:`idbench.report.scene.ellipsoid_axes`).

Nothing is fetched: it works from a ``file://`` URL and when mailed. Every
name and message (runs, estimators, errors) is JSON text the script shows with
``textContent``; the JSON is escaped so that no ``<`` ends the block.
"""

from __future__ import annotations

import base64
import hashlib
import json
from importlib import resources
from typing import Any

import numpy as np
import pandas as pd

from idbench.core.sanitize import printable
from idbench.report.scene import MM, Scenes, ellipsoid_axes, error_range
from idbench.report.summary import sweep_axes

COLOURS = [
    (68, 1, 84), (72, 40, 120), (62, 74, 137), (49, 104, 142), (38, 130, 142),
    (31, 158, 137), (53, 183, 121), (109, 205, 89), (180, 222, 44), (253, 231, 37),
]  # fmt: skip
"""The colour scale's stops (viridis), low to high error."""

TICKS = 5
"""Labels under the colour bar."""

STYLE = """
#view3d canvas { width: 100%; height: 480px; display: block; border: 1px solid #ddd;
  touch-action: none; }
#view3d.failed canvas, #view3d.failed .view-controls { display: none; }
#view3d .view-controls { margin: 0.4em 0; display: flex; flex-wrap: wrap;
  gap: 0.4em 1.2em; align-items: center; }
#view3d .view-note { color: #8a4b00; }
#view3d .view-message { color: #8a4b00; white-space: pre-wrap; }
#view3d .view-bar { height: 12px; width: 320px; border: 1px solid #aaa; }
#view3d .view-ticks { display: flex; justify-content: space-between; width: 320px;
  font-size: 0.8em; }
#view3d input[type=range] { width: 320px; }
#view3d .view-swatch { display: inline-block; width: 0.8em; height: 0.8em;
  margin-right: 0.3em; border: 1px solid #555; vertical-align: middle; }
#view3d .view-legend { font-size: 0.9em; }
tr.viewable { cursor: pointer; }
"""


def asset(name: str) -> str:
    """The text of ``idbench/report/assets/NAME``."""
    return (
        resources.files("idbench.report")
        .joinpath("assets", name)
        .read_text(encoding="utf-8")
    )


def _b64(array: Any) -> str:
    return base64.b64encode(np.ascontiguousarray(array).tobytes()).decode("ascii")


def _int16(values: Any) -> tuple[str, float]:
    """Values as int16 (base64) and the scale that gives them back."""
    values = np.nan_to_num(np.asarray(values, dtype=float))
    top = float(np.abs(values).max()) if values.size else 0.0
    scale = top / 32767 if top > 0 else 1.0
    return _b64(np.round(values / scale).astype("<i2")), scale


def _level(error: Any, top: float) -> str:
    """Errors (mm) as uint8 on [0, top] (base64); 255 where there is none."""
    e = np.asarray(error, dtype=float)
    q = np.round(254 * np.clip(np.nan_to_num(e, nan=0.0) / top, 0, 1))
    q[~np.isfinite(e)] = 255
    return _b64(q.astype(np.uint8))


LEGEND = (
    ("markers-observed", "#111111", "markers, observed"),
    ("markers-predicted", "#d6336c", "markers, predicted"),
    ("targets-true", "#2b8a3e", "targets, true"),
    ("targets-predicted", "#f08c00", "targets, predicted (95% region, last step)"),
)
"""The point sets the view draws: (key, colour, legend text)."""


def _points(arrays: Any, names: tuple[str, str]) -> dict[str, Any] | None:
    """Two stored position sets (S, n, 3) as float32 (base64), or None."""
    if not all(name in arrays for name in names):
        return None
    found = [np.asarray(arrays[name], dtype="<f4") for name in names]
    return {"n": int(found[0].shape[1]), **{
        name.partition("_")[2]: _b64(points) for name, points in zip(names, found,
                                                                     strict=True)
    }}  # fmt: skip


def _regions(arrays: Any) -> list[dict[str, Any]]:
    """Each target's 95% region at the last step: centre (3,), axes (9,)."""
    if "targets_cov" not in arrays:
        return []
    centres = np.asarray(arrays["targets_predicted"], dtype=float)[-1]
    out = []
    for centre, axes in zip(centres, ellipsoid_axes(arrays["targets_cov"]),
                            strict=True):  # fmt: skip
        if np.all(np.isfinite(centre)) and np.all(np.isfinite(axes)):
            out.append({"centre": centre.tolist(), "axes": axes.ravel().tolist()})
    return out


def _cloud(points: Any) -> dict[str, Any]:
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    lo, hi = p.min(axis=0), p.max(axis=0)
    scale = np.where(hi > lo, (hi - lo) / 65535, 1.0)
    q = np.round((p - lo) / scale).astype("<u2")
    return {"points": _b64(q), "offset": lo.tolist(), "scale": scale.tolist()}


def axes(runs: pd.DataFrame) -> list[str]:
    """The columns a run is chosen by.

    Scenario (if several), mesh, estimator, the sweep's axes, seed.
    """
    several = "scenario" in runs and runs["scenario"].nunique() > 1
    out = ["scenario"] if several else []
    out += ["mesh", "estimator"]
    out += [a for a in sweep_axes(runs) if a not in out and a != "seed"]
    return [a for a in out if a in runs.columns] + ["seed"]


def payload(scenes: Scenes, runs: pd.DataFrame) -> dict[str, Any]:
    """The view's data (JSON-able): surfaces, truths, clouds and runs."""
    empty = (
        "No 3D view: the runs of this folder stored no surface (their model "
        "has no surface(), or the folder was written by an older idbench)."
    )
    out: dict[str, Any] = {"problem": printable(scenes.problem), "empty": empty,
                           "colours": [list(c) for c in COLOURS], "unit": "mm",
                           "legend": {key: colour for key, colour, _ in LEGEND},
                           "axes": [], "meshes": [], "truths": [], "clouds": [],
                           "runs": [], "top": 1.0}  # fmt: skip
    if scenes.problem or not scenes.runs:
        return out
    top = error_range(scenes, runs)
    names = axes(runs)
    out.update(axes=names, top=top)
    meshes: dict[int, int] = {}
    truths: dict[int, int] = {}
    clouds: dict[str, int] = {}

    def mesh_index(surface: Any) -> int:
        if id(surface) not in meshes:
            meshes[id(surface)] = len(out["meshes"])
            out["meshes"].append({
                "vertices": _b64(surface.vertices.astype("<f4")),
                "triangles": _b64(surface.triangles.astype("<u4")),
            })  # fmt: skip
        return meshes[id(surface)]

    for _, row in runs.iterrows():
        run_id = str(row["run_id"])
        scene = scenes.runs.get(run_id)
        if scene is None:
            continue
        shown = scene.shown
        disp, scale = _int16(shown.displacement)
        entry: dict[str, Any] = {
            "id": printable(run_id),
            "labels": [printable(_value(row.get(a))) for a in names],
            "mesh": mesh_index(shown.surface),
            "steps": [int(k) for k in shown.steps],
            "total": int(row.get("steps", shown.steps[-1])),
            "disp": disp,
            "scale": scale,
            "err": None if scene.error_mm is None else _level(scene.error_mm, top),
            "truth": -1,
            "cloud": -1,
            "camera": None,
            "title": printable(_title(row, names)),
            "message": printable(_message(row, scene.error_mm is None)),
        }
        truth = scene.truth
        if truth is not None:
            if id(truth) not in truths:
                tdisp, tscale = _int16(truth.displacement)
                truths[id(truth)] = len(out["truths"])
                out["truths"].append({
                    "mesh": mesh_index(truth.surface), "disp": tdisp,
                    "scale": tscale, "steps": [int(k) for k in truth.steps],
                })  # fmt: skip
            entry["truth"] = truths[id(truth)]
        arrays = shown.arrays
        if "cloud_points" in arrays:
            points = np.asarray(arrays["cloud_points"])
            key = hashlib.sha256(points.tobytes()).hexdigest()
            if key not in clouds:
                clouds[key] = len(out["clouds"])
                out["clouds"].append(_cloud(points))
            entry["cloud"] = clouds[key]
            bits = np.packbits(np.asarray(arrays["cloud_outliers"], dtype=bool))
            entry["outliers"] = _b64(bits)
            entry["camera"] = [float(v) for v in np.asarray(arrays["camera"])]
        entry["markers"] = _points(arrays, ("markers_observed", "markers_predicted"))
        entry["targets"] = _points(arrays, ("targets_true", "targets_predicted"))
        if entry["targets"] is not None:
            entry["targets"]["regions"] = _regions(arrays)
        out["runs"].append(entry)
    return out


def _value(v: Any) -> str:
    return "" if v is None or (isinstance(v, float) and np.isnan(v)) else str(v)


def _title(row: Any, names: list[str]) -> str:
    parts = [f"{a} {_value(row.get(a))}" for a in names]
    text = ", ".join(parts) + f": {_value(row.get('status'))}"
    error = row.get("shape_error_mean_final")
    if isinstance(error, float) and np.isfinite(error):
        text += f"; shape error at the last step {MM * error:.3g} mm per grid point"
    return text


def _message(row: Any, no_truth: bool) -> str:
    lines = [_value(row.get("error")), _value(row.get("warning"))]
    if no_truth:
        lines.append("No truth field (a recording): the surface is not coloured.")
    return "\n".join(line for line in lines if line)


def _json(data: Any) -> str:
    """JSON for a ``<script>`` block: no ``<``, ``>`` or ``&`` left to end it."""
    text = json.dumps(data, separators=(",", ":"), allow_nan=False)
    for char, code in (("<", "\\u003c"), (">", "\\u003e"), ("&", "\\u0026")):
        text = text.replace(char, code)
    return text


def section(scenes: Scenes, runs: pd.DataFrame) -> str:
    """The view's HTML: heading, controls, canvas, colour bar, data and scripts."""
    data = payload(scenes, runs)
    ticks = "".join("<span></span>" for _ in range(TICKS))
    return "\n".join([
        f"<style>{STYLE}</style>",
        '<h2 id="view">3D view</h2>',
        '<div id="view3d">',
        "<p>Each run's surface at the stored steps, coloured by its displacement"
        " error against the truth at each vertex (mm; the truth's displacement"
        " at the closest point of its undeformed surface); the truth's surface"
        " translucent; a depth camera's cloud (blue, outliers the gate clips"
        " red) and frustum; the markers (observed and predicted) and the hidden"
        " targets (true and predicted, with each one's predicted 95% region at"
        " the last step), drawn through the surface. Drag to turn, scroll to"
        " zoom, right-drag to pan; click a row of the summary to show its"
        " runs.</p>",
        '<p class="view-note"></p>',
        '<div class="view-controls view-choices"></div>',
        '<div class="view-controls">',
        '<label>step <input type="range" id="view3d-step" min="0" max="0"'
        ' value="0"></label><span class="view-step"></span>',
        '<label><input type="checkbox" id="view3d-truth" checked> truth</label>',
        '<label><input type="checkbox" id="view3d-cloud" checked> cloud</label>',
        '<label><input type="checkbox" id="view3d-camera" checked> camera</label>',
        '<label><input type="checkbox" id="view3d-markers" checked> markers</label>',
        '<label><input type="checkbox" id="view3d-targets" checked> targets</label>',
        '<button type="button" id="view3d-reset">reset view</button>',
        "</div>",
        '<div class="view-controls view-legend">', *(
            f'<span data-layer="{key}"><span class="view-swatch" style="background:'
            f' {colour}"></span>{text}</span>' for key, colour, text in LEGEND
        ), "</div>",
        '<p class="view-info"></p><p class="view-message"></p>',
        '<canvas aria-label="3D view of the selected run"></canvas>',
        '<div class="view-controls"><span>displacement error, mm</span>',
        f'<div><div class="view-bar"></div><div class="view-ticks">{ticks}</div></div>',
        "</div></div>",
        f'<script type="application/json" id="view3d-data">{_json(data)}</script>',
        f"<script>{asset('vendor/three.min.js')}</script>",
        f"<script>{asset('view3d.js')}</script>",
    ])  # fmt: skip

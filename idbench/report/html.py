"""``report.html``: one self-contained page of a comparison, usable offline.

The page holds the manifest (versions, machine, settings), the summary table
with sortable columns and a metric selector, every figure as inline SVG, the
real-time frontier table, and links to the data: the parquet tables and the
manifest by relative link (they sit next to the page), the summary as a CSV
``data:`` URI. Nothing is fetched from a network: no CDN, no web font, the
styles and the few lines of JavaScript are inline.
"""

from __future__ import annotations

import base64
import html
import json
import re
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from idbench.core.sanitize import printable
from idbench.report.columns import (
    format_cell,
    headers,
    interval_columns,
    legend,
    seeds_note,
    status_for_people,
)
from idbench.report.intervals import format_interval, method
from idbench.report.paired import paired_html
from idbench.report.summary import parameter_names_of_summary

CAPTIONS = {
    "stiffness_vs_resolution": "Identified parameters against model resolution"
    " (one panel per parameter; mean over seeds, bars: 95% t interval).",
    "shape_error": "Shape error at the last step, mm per grid point: the model"
    " with the true values (direct) and with each estimator's values (mean over"
    " seeds, bars: 95% t interval).",
    "estimates_vs_step": "Estimates along the load path (first seed): colour"
    " the estimator, line style the mesh.",
    "uncertainty": "Reported uncertainty: share of seeds whose 95% interval"
    " holds the true value (filled) and the reference value (hollow), and the"
    " mean NEES against the true value (calibrated: p).",
    "maps": "Maps of a field (first seed of each run): each cell at its centroid"
    " in the slab through the truth's inclusion, coloured by log10(E / the"
    " truth's median); ringed: cells mostly inside the true inclusion.",
    "realtime_frontier": "Real-time frontier: shape error against wall time"
    " per step on this machine; the line is the Pareto front.",
}

KEY_COLUMNS = ("scenario", "model_nodes", "mesh", "estimator", "n", "status")

STYLE = """
body { font: 15px/1.45 system-ui, -apple-system, "Segoe UI", sans-serif;
  margin: 0 auto; max-width: 1500px; padding: 1em 2em; color: #222; }
h1 { font-size: 1.6em; margin-bottom: 0.2em; }
h2 { border-bottom: 1px solid #ccc; margin-top: 1.8em; }
table { border-collapse: collapse; font-size: 0.9em; margin: 0.6em 0; }
th, td { border: 1px solid #ddd; padding: 0.25em 0.55em; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
th { background: #f3f3f3; }
table.sortable th { cursor: pointer; user-select: none; max-width: 8em;
  vertical-align: bottom; }
table.sortable th[aria-sort="ascending"]::after { content: " \\25B2"; }
table.sortable th[aria-sort="descending"]::after { content: " \\25BC"; }
tr.notok td { color: #8a4b00; }
.scroll { overflow-x: auto; }
figure { margin: 1.2em 0; }
figure svg { max-width: 100%; height: auto; }
figcaption { color: #555; font-size: 0.9em; }
.meta td:first-child { font-weight: 600; }
.hidden { display: none; }
td.reason { min-width: 20em; }
label { margin-right: 0.5em; }
"""

SCRIPT = """
(function () {
  function cellValue(td) {
    var v = td.getAttribute("data-value");
    if (v === null || v === "") { return null; }
    var x = Number(v);
    return isNaN(x) ? v.toLowerCase() : x;
  }
  function sortBy(table, index, th) {
    var body = table.tBodies[0];
    var rows = Array.prototype.slice.call(body.rows);
    var asc = th.getAttribute("aria-sort") !== "ascending";
    Array.prototype.forEach.call(table.tHead.rows[0].cells, function (c) {
      c.removeAttribute("aria-sort");
    });
    th.setAttribute("aria-sort", asc ? "ascending" : "descending");
    rows.sort(function (a, b) {
      var x = cellValue(a.cells[index]), y = cellValue(b.cells[index]);
      if (x === y) { return 0; }
      if (x === null) { return 1; }
      if (y === null) { return -1; }
      var r = (typeof x === typeof y) ? (x < y ? -1 : 1)
        : (typeof x === "number" ? -1 : 1);
      return asc ? r : -r;
    });
    rows.forEach(function (r) { body.appendChild(r); });
  }
  document.querySelectorAll("table.sortable").forEach(function (table) {
    Array.prototype.forEach.call(table.tHead.rows[0].cells, function (th, i) {
      th.addEventListener("click", function () { sortBy(table, i, th); });
    });
  });
  var select = document.getElementById("metric");
  if (select) {
    select.addEventListener("change", function () {
      var want = select.value;
      document.querySelectorAll("#summary [data-metric]").forEach(function (c) {
        var show = want === "all" || c.getAttribute("data-metric") === want;
        c.classList.toggle("hidden", !show);
      });
    });
  }
})();
"""


def write_html(
    root: Path,
    runs: pd.DataFrame,
    summary: pd.DataFrame,
    frontier: pd.DataFrame,
    svgs: dict[str, str],
    paired: list[Any] | None = None,
    view: str = "",
    caveats: list[str] | None = None,
) -> Path:
    """Write ``root/report.html`` and return its path.

    Parameters
    ----------
    root
        The compare output directory (its ``manifest.json`` is read if there).
    runs
        The runs table.
    summary
        :func:`idbench.report.write.summarise` of ``runs``.
    frontier
        :func:`idbench.report.write.frontier` of the comparison (may be empty).
    svgs
        The figures' SVG text by stem, in the order to show them.
    paired
        Paired-difference tables (:class:`idbench.report.paired.Paired`) to show
        after the summary.
    view
        The 3D view's section (:func:`idbench.report.view3d.section`), shown
        after them.
    caveats
        Lines a reader must know before believing the numbers (flagged runs,
        disagreements, incomplete traces), shown as text after the summary.
    """
    manifest_path = root / "manifest.json"
    manifest = json.loads(manifest_path.read_text()) if manifest_path.exists() else {}
    counts = runs["status"].value_counts() if "status" in runs else pd.Series()
    status = ", ".join(f"{k} {v}" for k, v in counts.items())
    csv = base64.b64encode(summary.to_csv(index=False).encode()).decode()
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        "<title>idbench report</title>",
        f"<style>{STYLE}</style></head><body>",
        "<h1>idbench report</h1>",
        f"<p>{len(runs)} runs; status: {_text(status)}. Written "
        f"{datetime.now(UTC):%Y-%m-%d %H:%M} UTC from "
        f"<code>{html.escape(root.name)}</code>.</p>",
        f"<p>{_text(_machine(manifest))}</p>",
        "<h2>Data</h2><ul>",
        _link(root, "runs.parquet", "one row per run"),
        _link(root, "traces.parquet", "one row per run and step"),
        _link(root, "manifest.json", "versions, machine and settings"),
        f'<li><a download="summary.csv" href="data:text/csv;base64,{csv}">'
        "summary.csv</a> (the table below)</li></ul>",
        "<h2>Summary</h2>",
        "<p>Means over the ok runs of each row; n: runs (one a seed); shape"
        " errors in mm per grid point. Click a header to sort.</p>",
        f"<p>{html.escape(legend(summary))}</p>" if not summary.empty else "",
        _summary_table(summary, headers(summary)),
        *(f"<p>{html.escape(line)}</p>" for line in seeds_note(summary)),
        *_caveats(caveats or []),
        *(paired_html(p) for p in paired or []),
        view,
    ]
    if svgs:
        parts.append("<h2>Figures</h2>")
    for stem, svg in svgs.items():
        caption = CAPTIONS.get(stem, stem)
        parts.append(
            f'<figure id="fig-{stem}">{_inline_svg(svg, stem)}'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>"
        )
    if not frontier.empty:
        parts += [
            "<h2>Real-time frontier</h2>",
            "<p>Wall time per step: the larger of the median estimator step and"
            " the total estimator time / steps, measured on this machine.</p>",
            '<div class="scroll">',
            _table(frontier, {c: c for c in frontier.columns}, "frontier"),
            "</div>",
        ]
    parts += ["<h2>Manifest</h2>", _manifest(manifest)]
    parts += [f"<script>{SCRIPT}</script>", "</body></html>"]
    path = root / "report.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path


def _link(root: Path, name: str, what: str) -> str:
    if not (root / name).exists():
        return f"<li>{name}: not written</li>"
    size = (root / name).stat().st_size / 1024
    return (
        f'<li><a href="{name}" download>{name}</a> ({what}; {size:.0f} kB,'
        " next to this file)</li>"
    )


def _summary_table(summary: pd.DataFrame, names: dict[str, str]) -> str:
    """The summary with a metric selector: key columns stay, metrics toggle."""
    if summary.empty:
        return "<p>(no runs)</p>"
    hidden = {"ok", "reason", *interval_columns(summary)}
    cols = [c for c in summary.columns if c not in hidden]
    if "reason" in summary and summary["reason"].astype(bool).any():
        cols.append("reason")  # last, as in the text table
    metrics = [
        c
        for c in cols
        if c not in KEY_COLUMNS and c != "reason" and _numeric(summary[c])
    ]
    metrics = [c for c in metrics if c not in _axes(summary)]
    shown = summary[cols].assign(status=status_for_people(summary))
    options = "".join(
        f'<option value="{html.escape(m)}">{html.escape(names.get(m, m))}</option>'
        for m in metrics
    )
    select = (
        '<p><label for="metric">Metric:</label><select id="metric">'
        f'<option value="all">all metrics</option>{options}</select></p>'
    )
    return (
        select
        + '<div class="scroll">'
        + _table(shown, names, "summary", set(metrics), summary)
        + "</div>"
    )


def _axes(summary: pd.DataFrame) -> list[str]:
    params = set(parameter_names_of_summary(summary))
    fixed = {"settling_step", "shape_error_mm", "direct_mm", "transfer_mm"}
    fixed |= {"n_solves", "wall_s_step"}
    out = []
    bounds = interval_columns(summary)
    for c in summary.columns:
        base = c.rpartition("_")[0]
        if c in KEY_COLUMNS or c in ("ok", "reason") or c in fixed or base in params:
            continue
        if c in bounds:
            continue
        out.append(c)
    return out


def _numeric(col: pd.Series) -> bool:
    return bool(pd.api.types.is_numeric_dtype(col)) and not pd.api.types.is_bool_dtype(
        col
    )


def _table(
    df: pd.DataFrame,
    names: dict[str, str],
    ident: str,
    metrics: set[str] | None = None,
    bounds: pd.DataFrame | None = None,
) -> str:
    """A sortable HTML table; cells carry their raw value for sorting.

    With ``bounds`` (the full summary), a metric ``m`` with ``m_lo`` and
    ``m_hi`` columns there shows its interval (``3257 +- 4``), its exact
    bounds in the cell's title. Every string goes through
    :func:`idbench.core.sanitize.printable` and ``html.escape``.
    """
    metrics = metrics or set()
    bounds = bounds if bounds is not None else pd.DataFrame()

    def attrs(col: str) -> str:
        return f' data-metric="{html.escape(col)}"' if col in metrics else ""

    head = "".join(
        f'<th scope="col"{attrs(c)} title="{_text(c)}">{_text(names.get(c, c))}</th>'
        for c in df.columns
    )
    numeric = {c: _numeric(df[c]) for c in df.columns}
    body = []
    ranges = {
        c: bounds[[f"{c}_lo", f"{c}_hi"]].to_numpy(dtype=float)
        for c in df.columns
        if f"{c}_lo" in bounds and f"{c}_hi" in bounds
    }  # rows in df's order
    for j, (_, row) in enumerate(df.iterrows()):
        cells = []
        for c in df.columns:
            v = row[c]
            raw = "" if _missing(v) else str(v)
            cls = ' class="num"' if numeric[c] else ""
            cls = ' class="reason"' if c == "reason" else cls
            text, title = format_cell(v), ""
            if c in ranges:
                lo, hi = ranges[c][j]
                text = format_interval(v, lo, hi, c, text)
                if np.isfinite(lo) and np.isfinite(hi):
                    title = f' title="95% {method(c)}: {lo:.6g} to {hi:.6g}"'
            cells.append(
                f'<td{cls}{attrs(c)}{title} data-value="{_text(raw)}">'
                f"{_text(text, join_lines=c == 'reason')}</td>"
            )
        notok = row.get("status", "ok") not in ("ok", True) and "status" in df
        tr = '<tr class="notok">' if notok else "<tr>"
        body.append(tr + "".join(cells) + "</tr>")
    return (
        f'<table id="{ident}" class="sortable"><thead><tr>{head}</tr></thead>'
        f"<tbody>{''.join(body)}</tbody></table>"
    )


def _caveats(lines: list[str]) -> list[str]:
    """The caveats section's HTML (none without lines)."""
    if not lines:
        return []
    return ["<h2>Caveats</h2><ul>", *(f"<li>{_text(c)}</li>" for c in lines), "</ul>"]


def _text(value: Any, join_lines: bool = False) -> str:
    """A string from a plugin or a results file, for HTML: printable, escaped."""
    return html.escape(printable(value, join_lines=join_lines))


def _missing(v: Any) -> bool:
    return v is None or (isinstance(v, float | np.floating) and not np.isfinite(v))


def _inline_svg(svg: str, stem: str) -> str:
    """Matplotlib's SVG file as inline markup, its ids prefixed to stay unique."""
    start = svg.find("<svg")
    svg = svg[start:] if start >= 0 else svg
    svg = re.sub(r"<metadata>.*?</metadata>", "", svg, flags=re.DOTALL)
    svg = re.sub(
        r'(\bid="|url\(#|href="#)([^"\)]+)',
        lambda m: f"{m.group(1)}{stem}-{m.group(2)}",
        svg,
    )
    return svg.replace("<svg ", f'<svg role="img" aria-label="{stem}" ', 1)


def _manifest(manifest: dict[str, Any]) -> str:
    if not manifest:
        return "<p>(no manifest.json)</p>"
    rows: list[tuple[str, str]] = []
    for key in ("python", "platform", "cpu_count"):
        if key in manifest:
            rows.append((key, str(manifest[key])))
    for name, version in (manifest.get("versions") or {}).items():
        rows.append((f"version of {name}", str(version)))
    for name, value in (manifest.get("threads") or {}).items():
        rows.append((name, "unset" if value is None else str(value)))
    table = "".join(f"<tr><td>{_text(k)}</td><td>{_text(v)}</td></tr>" for k, v in rows)
    settings = json.dumps(manifest.get("settings", {}), indent=1)
    return (
        f'<table class="meta">{table}</table><h3>Settings</h3>'
        f"<pre>{html.escape(settings)}</pre>"
    )


def _machine(manifest: dict[str, Any]) -> str:
    """One line: idbench version, Python, platform, CPUs."""
    versions = manifest.get("versions") or {}
    parts = [
        f"idbench {versions['idbench']}" if "idbench" in versions else "",
        f"Python {manifest['python']}" if "python" in manifest else "",
        str(manifest.get("platform", "")),
        f"{manifest['cpu_count']} CPUs" if "cpu_count" in manifest else "",
    ]
    text = ", ".join(p for p in parts if p)
    return f"Machine: {text} (details under Manifest)." if text else ""

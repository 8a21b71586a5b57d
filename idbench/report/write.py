"""The report of a comparison: frontier table, figures, report.md and report.html.

The summary itself lives in :mod:`idbench.report.summary`, its columns in
:mod:`idbench.report.columns` and its text in :mod:`idbench.report.text`
(re-exported here).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from idbench.core.sanitize import markdown_cell
from idbench.report.caveats import caveat_lines
from idbench.report.columns import headers, legend, seeds_note
from idbench.report.maps import is_field, map_figure
from idbench.report.paired import Paired, paired_markdown
from idbench.report.summary import parameter_names, summarise, sweep_axes
from idbench.report.text import (
    FORMATS,
    flagged_lines,
    markdown_table,
    summary_text,
)
from idbench.store import lock

__all__ = [
    "BUDGETS_HZ",
    "FORMATS",
    "figures",
    "frontier",
    "frontier_display",
    "frontier_figure",
    "headers",
    "pareto_front",
    "parameter_names",
    "summarise",
    "summary_text",
    "sweep_axes",
    "write_report",
]

BUDGETS_HZ = (30, 60)
VIEW_NOTE = (
    "The best and the worst run (by shape error at the last step) at their last"
    " stored step, coloured by the displacement error against the truth (mm)."
    " Every run, at every stored step, is in report.html's 3D view: open it"
    " in a browser, or run `idbench view DIR`."
)
FRONTIER_KEYS = ["scenario", "mesh", "model_nodes", "estimator"]


def frontier(
    runs: pd.DataFrame, traces: pd.DataFrame, budgets_hz: tuple[int, ...] = BUDGETS_HZ
) -> pd.DataFrame:
    r"""Shape error reached against wall time per step, per (mesh, estimator).

    Only runs with status ok count; sparsity settings and seeds are pooled, as
    in :func:`summarise`. The wall time of a step is the estimator's
    ``update`` time (the traces' ``wall_s``: per step, not cumulative; the
    harness's metrics solves are not in it). Per (mesh, estimator) it is

    .. math::

        t_{step} = \max(\operatorname{median}_{k, s} w_{k,s},
                         \operatorname{mean}_s \tfrac{1}{K} \sum_k w_{k,s}),

    the larger of the typical step (median over steps and seeds) and the
    amortised step (total estimator time / K, mean over seeds). A filter works
    evenly and is charged its typical step; an estimator that defers its work
    (``batch-ls`` with ``refit="end"`` fits once at step K and costs nothing
    before) is charged its amortised cost, which a real-time loop could only
    meet by spreading the fit over the steps. Without traces, ``wall_s_step``
    of the runs (the mean step) is used.

    Parameters
    ----------
    runs, traces
        The tables of a comparison (``runs.parquet``, ``traces.parquet``).
    budgets_hz
        Real-time rates; each gives a column ``within_<rate>hz`` (the step
        fits in 1/rate seconds) and ``best_<rate>hz`` (the row of lowest shape
        error among those, per scenario).

    Returns
    -------
    pandas.DataFrame
        One row per (scenario, mesh, model_nodes, estimator), sorted by
        scenario and wall time: ``seeds``, ``shape_error_final``,
        ``shape_error_mean_final`` (means over seeds), ``wall_s_median``,
        ``wall_s_amortised``, ``wall_s_step``, ``rate_hz`` (1 / wall_s_step),
        ``pareto`` (no other row of the scenario is at least as fast and at
        least as accurate, and strictly better in one), and the budget columns.
    """
    ok = runs[runs["status"] == "ok"] if "status" in runs else runs
    if ok.empty or "shape_error_final" not in ok:
        return pd.DataFrame()
    keys = [k for k in FRONTIER_KEYS if k in ok.columns]
    agg: dict[str, Any] = {
        "seeds": ("run_id", "size"),
        "shape_error_final": ("shape_error_final", "mean"),
        "shape_error_mean_final": ("shape_error_mean_final", "mean"),
    }
    agg = {k: v for k, v in agg.items() if v[0] in ok.columns}
    table = ok.groupby(keys, dropna=False, sort=True).agg(**agg)
    if not traces.empty and "wall_s" in traces:
        tr = traces.merge(ok[["run_id", *keys]], on="run_id")
        per_run = tr.groupby("run_id")["wall_s"].agg(["sum", "size"])
        amortised = ok.set_index("run_id")[keys].join(per_run)
        amortised["wall_s"] = amortised["sum"] / amortised["size"]
        table["wall_s_median"] = tr.groupby(keys, dropna=False)["wall_s"].median()
        table["wall_s_amortised"] = amortised.groupby(keys, dropna=False)[
            "wall_s"
        ].mean()
    else:
        mean_step = ok.groupby(keys, dropna=False)["wall_s_step"].mean()
        table["wall_s_median"] = mean_step
        table["wall_s_amortised"] = mean_step
    table["wall_s_step"] = table[["wall_s_median", "wall_s_amortised"]].max(axis=1)
    table["rate_hz"] = 1.0 / table["wall_s_step"]
    table = table.reset_index()
    parts = []
    by = ["scenario"] if "scenario" in keys else []
    groups = list(table.groupby(by, sort=True)) if by else [((), table)]
    for _, df in groups:
        df = df.sort_values(["wall_s_step", "shape_error_final"]).copy()
        df["pareto"] = pareto_front(
            df["wall_s_step"].to_numpy(), df["shape_error_final"].to_numpy()
        )
        for hz in budgets_hz:
            within = df["wall_s_step"] <= 1.0 / hz
            df[f"within_{hz}hz"] = within
            best = df.loc[within, "shape_error_final"]
            df[f"best_{hz}hz"] = False
            if best.notna().any():
                df.loc[best.idxmin(), f"best_{hz}hz"] = True
        parts.append(df)
    return pd.concat(parts).reset_index(drop=True)


def pareto_front(cost: np.ndarray, error: np.ndarray) -> np.ndarray:
    """Which points no other point dominates (lower is better on both axes).

    Point i is dominated when some j has cost_j <= cost_i and
    error_j <= error_i with at least one strict. NaN points are never on the
    front and dominate nothing.

    Parameters
    ----------
    cost, error
        (n,) arrays.

    Returns
    -------
    numpy.ndarray
        (n,) booleans.
    """
    c = np.asarray(cost, dtype=float)[:, None]
    e = np.asarray(error, dtype=float)[:, None]
    finite = np.isfinite(c[:, 0]) & np.isfinite(e[:, 0])
    no_worse = (c.T <= c) & (e.T <= e)  # [i, j]: j is no worse than i
    better = (c.T < c) | (e.T < e)
    dominated = (no_worse & better & finite[None, :]).any(axis=1)
    return finite & ~dominated


def figures(
    runs: pd.DataFrame, traces: pd.DataFrame, study: pd.DataFrame | None = None
) -> dict[str, Any]:
    """The report's figures (matplotlib), by file stem.

    ``stiffness_vs_resolution`` (one panel per parameter), ``shape_error``
    (one per scenario), ``estimates_vs_step`` (one per parameter) and
    ``uncertainty`` (coverage per parameter and NEES; needs a reported std)
    need ok runs and a parameter; ``realtime_frontier`` is always drawn (it says so
    when no run is ok). See :mod:`idbench.report.figures`.
    """
    import matplotlib

    matplotlib.use("Agg")
    from idbench.report import figures as fg

    figs: dict[str, Any] = {}
    ok = runs[runs["status"] == "ok"] if "status" in runs else runs
    names = parameter_names(runs)
    axes = [a for a in sweep_axes(runs) if a in ok.columns]
    if not ok.empty and is_field(ok, names):  # maps, not a panel per cell
        figs["maps"] = map_figure(ok, names)
        names = []
    if not ok.empty and names:
        figs["stiffness_vs_resolution"] = fg.parameters_vs_resolution(
            ok, names, axes, study
        )
    column = "shape_error_mean_final"
    shaped = column in ok and bool(ok[column].notna().any())
    if not ok.empty and shaped:  # none on a recording (no truth field)
        figs["shape_error"] = fg.shape_error_vs_resolution(ok, axes, study)
    if not ok.empty and not traces.empty and names and names[0] in traces:
        figs["estimates_vs_step"] = fg.estimates_vs_step(ok, traces, names, axes)
    covered = [f"{n}_cover95_true" for n in names]
    if not ok.empty and names and all(c in ok for c in covered):
        if ok[covered].notna().any().any():
            figs["uncertainty"] = fg.uncertainty_vs_resolution(ok, names, axes)
    table = frontier(runs, traces)
    if not shaped:  # no shape error to draw: the figure says no run has one
        table = table.iloc[0:0]
    figs["realtime_frontier"] = fg.frontier_figure(table, BUDGETS_HZ)
    return figs


def frontier_display(table: pd.DataFrame) -> pd.DataFrame:
    """The :func:`frontier` table for people: shape error in mm per grid point."""
    if table.empty or "shape_error_mean_final" not in table:
        return table
    out = table.drop(columns=["shape_error_final", "shape_error_mean_final"])
    out.insert(
        list(table.columns).index("shape_error_final"),
        "shape_error_mm",
        1000.0 * table["shape_error_mean_final"],
    )
    return out


def frontier_figure(table: pd.DataFrame) -> Any:
    """Shape error against wall time per step; see :mod:`idbench.report.figures`."""
    from idbench.report.figures import frontier_figure as draw

    return draw(table, BUDGETS_HZ)


def write_report(
    directory: str | Path,
    study: pd.DataFrame | None = None,
    paired: list[Paired] | None = None,
    *,
    wait: bool = False,
) -> list[Path]:
    """Write figures (PNG, SVG), ``report.md`` and ``report.html`` for DIR.

    Parameters
    ----------
    directory
        A compare output (``runs.parquet``, ``traces.parquet``,
        ``manifest.json``).
    study
        Values the original study reported, overlaid on the figures (columns
        ``figure``, ``x``, ``y``, optional ``label``). Default: DIR's
        ``study_values.csv`` if there is one.
    paired
        Paired-difference tables (:func:`idbench.report.paired.paired_differences`
        of DIR's runs) to add after the summary.
    wait
        If another process is writing DIR (a compare), wait until it is done;
        by default that is refused (:class:`~idbench.store.lock.FolderBusy`).

    Returns
    -------
    list of pathlib.Path
        The files written.
    """
    root = Path(directory)
    runs_path = root / "runs.parquet"
    if not runs_path.exists():
        raise FileNotFoundError(f"{runs_path} not found: is {root} a compare output?")
    with lock.hold(root, wait=wait, hint="; wait for it (--wait)"):
        return _write_report(root, study, paired)


def _write_report(
    root: Path, study: pd.DataFrame | None, paired: list[Paired] | None
) -> list[Path]:
    """:func:`write_report`'s work, with DIR's lock held."""
    import matplotlib.pyplot as plt

    from idbench.report.html import write_html
    from idbench.report.scene import read_scenes
    from idbench.report.stills import write_stills
    from idbench.report.view3d import section

    runs_path, traces_path = root / "runs.parquet", root / "traces.parquet"
    runs = pd.read_parquet(runs_path)
    traces = pd.read_parquet(traces_path) if traces_path.exists() else pd.DataFrame()
    if study is None and (root / "study_values.csv").exists():
        study = pd.read_csv(root / "study_values.csv")
    written = []
    svgs: dict[str, str] = {}
    for stem, fig in figures(runs, traces, study).items():
        for ext in ("png", "svg"):
            path = root / f"{stem}.{ext}"
            fig.savefig(path, dpi=110, bbox_inches="tight")
            written.append(path)
        svgs[stem] = (root / f"{stem}.svg").read_text()
        plt.close(fig)
    summary = summarise(runs)
    table = frontier(runs, traces)
    lines = [
        "# idbench report",
        "",
        f"{len(runs)} runs; status: "
        + ", ".join(
            f"{markdown_cell(k)} {v}" for k, v in runs["status"].value_counts().items()
        ),
        "",
        "## Summary",
        "",
        "Means over the ok runs of each row; n: runs (one a seed). Shape errors"
        " in mm per grid point.",
        "",
        markdown_table(summary, headers(summary)),
        "",
        *(markdown_cell(x) + "\n" for x in [legend(summary)] if not summary.empty),
        *(markdown_cell(x) + "\n" for x in seeds_note(summary)),
        *_markdown_flags(runs),
    ]
    told = caveat_lines(runs, traces, markdown=True)  # (the flags are listed above)
    if told:  # what a reader must know before believing the numbers
        lines += ["## Caveats", "", *(f"- {x}" for x in told), ""]
    caveats = [*flagged_lines(runs), *caveat_lines(runs, traces)]  # the page's
    for p in paired or []:
        lines += [paired_markdown(p), ""]
    if not table.empty:
        lines += [
            "## Real-time frontier",
            "",
            "Wall time per step: the larger of the median estimator step and the"
            " total estimator time / steps (amortised), measured on this machine;"
            " `pareto`: no other row is at least as fast and as accurate and"
            " strictly better in one;"
            " `best_<rate>hz`: lowest shape error within that budget.",
            "",
            markdown_table(frontier_display(table)),
            "",
        ]
    lines += [f"![{p.stem}]({p.name})" for p in written if p.suffix == ".png"]
    scenes = read_scenes(root, runs)
    stills = write_stills(root, runs, scenes)
    if scenes.problem:
        note = f"No 3D view: this folder fails its checks: {scenes.problem}"
    else:
        note = VIEW_NOTE if scenes.runs else "No 3D view: no run stored a surface."
    lines += ["", "## 3D view", "", markdown_cell(note), ""]
    lines += [f"![{p.stem}]({p.name})" for p in stills]
    written += stills
    md = root / "report.md"
    md.write_text("\n".join(lines) + "\n")
    written.append(md)
    written.append(
        write_html(
            root, runs, summary, frontier_display(table), svgs, paired,
            section(scenes, runs), caveats=caveats,
        )
    )
    return written


def _markdown_flags(runs: pd.DataFrame) -> list[str]:
    """The summary's flagged lines (warnings, loads) as markdown lists."""
    out = []
    for line in flagged_lines(runs, markdown=True):
        if line.startswith("  "):
            out.append(f"- {line.strip()}")
        else:
            out += ["", line, ""]
    return [*out, ""] if out else []

"""Summaries and figures of a comparison's results."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd


def summarise(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per (scenario, mesh, estimator): means over seeds and settings."""
    if runs.empty:
        return pd.DataFrame()
    df = runs.copy()
    df["E_ratio"] = df.get("E_final", np.nan) / df.get("E_true", np.nan)
    keys = ["scenario", "mesh", "model_nodes", "estimator"]
    agg: dict[str, Any] = {
        "runs": ("run_id", "size"),
        "ok": ("status", lambda s: int((s == "ok").sum())),
        "E_final": ("E_final", "mean"),
        "E_ratio": ("E_ratio", "mean"),
        "E_ref": ("E_ref", "mean"),
        "settling_step": ("settling_step", "mean"),
        "shape_error_final": ("shape_error_final", "mean"),
        "shape_error_direct": ("shape_error_direct", "mean"),
        "transfer_error": ("transfer_error", "mean"),
        "n_solves": ("n_solves", "mean"),
        "wall_s_step": ("wall_s_step", "mean"),
    }
    agg = {k: v for k, v in agg.items() if v[0] in df.columns}
    return df.groupby(keys, dropna=False, sort=True).agg(**agg).reset_index()


BUDGETS_HZ = (30, 60)
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


SUMMARY_COLUMNS = {
    "scenario": "scenario",
    "model_nodes": "nodes",
    "estimator": "estimator",
    "ok": "ok",
    "E_final": "E final",
    "E_ratio": "E/E_true",
    "E_ref": "E_ref",
    "settling_step": "settle",
    "shape_error_final": "shape err",
    "shape_error_direct": "direct",
    "transfer_error": "transfer",
    "n_solves": "solves",
    "wall_s_step": "s/step",
}


def summary_table(runs: pd.DataFrame) -> Any:
    """A rich table of :func:`summarise`, grouped by mesh and estimator."""
    from rich.table import Table

    summary = summarise(runs)
    table = Table(title="idbench compare: means over seeds")
    if summary.empty:
        table.add_column("no runs")
        return table
    cols = [c for c in SUMMARY_COLUMNS if c in summary.columns]
    for col in cols:
        text = not pd.api.types.is_numeric_dtype(summary[col])
        table.add_column(SUMMARY_COLUMNS[col], justify="left" if text else "right")
    for _, row in summary.iterrows():
        table.add_row(*(_fmt(row[c]) for c in cols))
    return table


def _fmt(v: Any) -> str:
    if isinstance(v, float | np.floating):
        if not np.isfinite(v):
            return "-"
        return f"{v:.4g}"
    return str(v)


def _figures(runs: pd.DataFrame, traces: pd.DataFrame) -> dict[str, Any]:
    """The report's figures (matplotlib), by file stem."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figs: dict[str, Any] = {}
    ok = runs[runs["status"] == "ok"] if "status" in runs else runs
    if ok.empty or "E_final" not in ok:
        return figs
    # identified E against model resolution, one line per estimator
    fig, ax = plt.subplots(figsize=(6, 4))
    for est, df in ok.groupby("estimator"):
        e = df.groupby("model_nodes")["E_final"].mean()
        ax.plot(e.index.to_numpy(), e.to_numpy(), "o-", label=str(est))
    ax.axhline(float(ok["E_true"].iloc[0]), color="k", ls="--", label="E_true")
    ax.set(
        xscale="log",
        xlabel="model nodes",
        ylabel="identified E (Pa)",
        title="Identified stiffness against resolution",
    )
    ax.legend(fontsize="small")
    figs["stiffness_vs_resolution"] = fig
    # shape error: direct simulation with E_true against assimilation
    fig, ax = plt.subplots(figsize=(6, 4))
    d = ok.groupby("model_nodes")["shape_error_direct"].mean()
    ax.plot(d.index.to_numpy(), d.to_numpy(), "ks--", label="direct (E_true)")
    for est, df in ok.groupby("estimator"):
        h = df.groupby("model_nodes")["shape_error_final"].mean()
        ax.plot(h.index.to_numpy(), h.to_numpy(), "o-", label=str(est))
    ax.set(
        xscale="log",
        xlabel="model nodes",
        ylabel="shape error (m, sum over grid)",
        title="Shape error at the last step",
    )
    ax.legend(fontsize="small")
    figs["shape_error"] = fig
    # effective E along the path, per scenario and mesh (first seed)
    if not traces.empty and "E" in traces:
        tr = traces.merge(ok[["run_id", "scenario", "mesh", "estimator", "seed"]])
        tr = tr[tr["seed"] == tr["seed"].min()]
        fig, ax = plt.subplots(figsize=(6, 4))
        for (scen, mesh, est), df in tr.groupby(["scenario", "mesh", "estimator"]):
            ax.plot(df["step"], df["E"], label=f"{scen} {mesh} {est}", lw=1)
        ax.set(
            xlabel="load step",
            ylabel="estimate of E (Pa)",
            title="Estimates along the load path",
        )
        ax.legend(fontsize="xx-small", ncol=2)
        figs["estimates_vs_step"] = fig
    table = frontier(runs, traces)
    if not table.empty:
        figs["realtime_frontier"] = frontier_figure(table)
    return figs


def frontier_figure(table: pd.DataFrame) -> Any:
    """Shape error against wall time per step (log-log), from :func:`frontier`.

    One marker per (mesh, estimator), labelled with its node count; one colour
    per estimator; vertical lines at the real-time budgets; the Pareto front of
    each scenario as a step line.
    """
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    scenarios = sorted(table["scenario"].unique()) if "scenario" in table else [None]
    markers = "osD^v<>"
    labelled: list[tuple[float, float, float]] = []
    for i, (est, df) in enumerate(table.groupby("estimator", sort=True)):
        for j, scen in enumerate(scenarios):
            d = df if scen is None else df[df["scenario"] == scen]
            label = str(est) if len(scenarios) == 1 else f"{est} {scen}"
            ax.plot(
                d["wall_s_step"],
                d["shape_error_final"],
                markers[j % len(markers)],
                color=f"C{i}",
                label=label,
                ms=6,
            )
            for _, row in d.iterrows():
                here = (
                    row["model_nodes"],
                    row["wall_s_step"],
                    row["shape_error_final"],
                )
                if any(_near(here, q) for q in labelled):
                    continue  # an equal mesh's label is already there
                labelled.append(here)
                ax.annotate(
                    f"{row['model_nodes']:.0f}",
                    (row["wall_s_step"], row["shape_error_final"]),
                    xytext=(4, 3),
                    textcoords="offset points",
                    fontsize="x-small",
                )
    for scen in scenarios:
        d = table if scen is None else table[table["scenario"] == scen]
        front = d[d["pareto"]].sort_values("wall_s_step")
        ax.plot(
            front["wall_s_step"],
            front["shape_error_final"],
            "k-",
            drawstyle="steps-post",
            lw=0.8,
            alpha=0.6,
            label="Pareto front" if scen == scenarios[0] else None,
        )
    for hz, ls in zip(BUDGETS_HZ, ("--", ":"), strict=False):
        ax.axvline(1.0 / hz, color="grey", ls=ls, lw=1, label=f"{hz} Hz budget")
    ax.set(
        xscale="log",
        yscale="log",
        xlabel="wall time per step (s)",
        ylabel="shape error at the last step (m, sum over grid)",
        title="Real-time frontier: accuracy against cost per step",
    )
    ax.legend(fontsize="x-small")
    return fig


def _near(a: tuple[float, float, float], b: tuple[float, float, float]) -> bool:
    """Same node count and within 15% on both axes of a log-log plot."""
    return bool(
        a[0] == b[0]
        and abs(np.log(a[1] / b[1])) < 0.14
        and abs(np.log(a[2] / b[2])) < 0.14
    )


def write_report(directory: str | Path) -> list[Path]:
    """Write figures (PNG and SVG) and ``report.md`` for a compare output DIR.

    Returns
    -------
    list of pathlib.Path
        The files written.
    """
    import matplotlib.pyplot as plt

    root = Path(directory)
    runs_path, traces_path = root / "runs.parquet", root / "traces.parquet"
    if not runs_path.exists():
        raise FileNotFoundError(f"{runs_path} not found: is {root} a compare output?")
    runs = pd.read_parquet(runs_path)
    traces = pd.read_parquet(traces_path) if traces_path.exists() else pd.DataFrame()
    written = []
    for stem, fig in _figures(runs, traces).items():
        for ext in ("png", "svg"):
            path = root / f"{stem}.{ext}"
            fig.savefig(path, dpi=110)
            written.append(path)
        plt.close(fig)
    summary = summarise(runs)
    lines = [
        "# idbench report",
        "",
        f"{len(runs)} runs; status: "
        + ", ".join(f"{k} {v}" for k, v in runs["status"].value_counts().items()),
        "",
        "## Means over seeds",
        "",
        _markdown(summary),
        "",
    ]
    table = frontier(runs, traces)
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
            _markdown(table),
            "",
        ]
    lines += [f"![{p.stem}]({p.name})" for p in written if p.suffix == ".png"]
    md = root / "report.md"
    md.write_text("\n".join(lines) + "\n")
    written.append(md)
    return written


def _markdown(df: pd.DataFrame) -> str:
    if df.empty:
        return "(no runs)"
    head = "| " + " | ".join(map(str, df.columns)) + " |"
    rule = "|" + "---|" * len(df.columns)
    body = [
        "| " + " | ".join(_fmt(v) for v in row) + " |"
        for row in df.itertuples(index=False)
    ]
    return "\n".join([head, rule, *body])

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
    return figs


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

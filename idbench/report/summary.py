"""The summary of a comparison: one row per swept combination, as data.

:func:`summarise` groups the runs table by scenario, mesh, estimator and every
axis the sweep varied (seeds pooled, counted in ``n``). It works for any
model: parameters are found by their columns (:func:`parameter_names`).
Every mean carries its 95% interval over seeds
(:mod:`idbench.report.intervals`): ``x_lo`` and ``x_hi`` columns. The
columns as people see them are :mod:`idbench.report.columns`; the summary as
text (a plain table that is never cut, markdown, csv or json) is
:func:`idbench.report.text.summary_text`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from idbench.report.intervals import interval
from idbench.report.maps import is_field
from idbench.score.maps import COLUMNS

SEED_COLUMNS = ("run_id", "seed", "model_nodes", "truth_nodes")
"""Description columns that never make a summary row of their own."""


def parameter_names(runs: pd.DataFrame) -> list[str]:
    """The model's parameter names, from the runs table's columns.

    A parameter ``x`` has a ``x_final`` column and a ``x_true`` or ``x_ref``
    column (``E_final``/``E_true``, ``k_final``/``k_ref``,
    ``E_region0_final``...); ``shape_error_*`` and ``*_std_final`` are not
    parameters.

    Examples
    --------
    >>> parameter_names(pd.DataFrame(columns=["k_true", "k_final", "k_ref"]))
    ['k']
    """
    names = []
    for col in runs.columns:
        if not col.endswith("_final") or col.startswith("shape_error"):
            continue
        name = col[: -len("_final")]
        if name.endswith("_std"):
            continue
        if f"{name}_true" in runs.columns or f"{name}_ref" in runs.columns:
            names.append(name)
    return names


def sweep_axes(runs: pd.DataFrame) -> list[str]:
    """Description columns that vary across the runs (the sweep's axes).

    The description of a run is every column before ``status`` (what
    :func:`idbench.run.harness.base_row` writes) and the true parameter values;
    ids, seeds and node counts are left out. A column is an axis when it takes
    more than one value for the same (scenario, mesh, estimator), so settings
    that differ only between estimators are not. The columns that always make
    a row (scenario, mesh, estimator) are not repeated here.
    """
    if "status" not in runs.columns:
        return []
    cols = list(runs.columns)
    described = cols[: cols.index("status")]
    names = parameter_names(runs)
    if not is_field(runs, names):  # a field's true values are no axis
        described += [f"{n}_true" for n in names if f"{n}_true" in cols]
    keys = [k for k in ROW_KEYS if k in cols and k != "model_nodes"]
    axes = []
    for col in described:
        if col in SEED_COLUMNS or col in ROW_KEYS:
            continue
        values = runs[col].astype(str)
        if keys:  # varies within one (scenario, mesh, estimator)
            varies = bool((values.groupby([runs[k] for k in keys]).nunique() > 1).any())
        else:
            varies = bool(values.nunique() > 1)
        if varies:
            axes.append(col)
    return axes


COVERAGE = ("68_true", "95_true", "68_ref", "95_ref")
"""Coverage columns of a parameter x: ``x_cover68_true`` ..."""


ROW_KEYS = ("scenario", "model_nodes", "mesh", "estimator")
"""What always separates summary rows, in their sort order."""


def summarise(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per (scenario, mesh, estimator) and combination of swept axes.

    Every description column that varies across runs (:func:`sweep_axes`:
    noise, obs_every, obs_points, settings, ...) is a key, so nothing a sweep
    varied is averaged away; seeds are pooled and counted in ``n``. Rows sort
    by scenario, model nodes (numeric), mesh, estimator, then the axes.

    Parameters
    ----------
    runs
        The runs table of a comparison.

    Returns
    -------
    pandas.DataFrame
        The keys; ``n`` (runs), ``ok`` (runs with status ok), ``status``
        (``ok``, or each status with its count), ``reason`` (the distinct
        error texts of runs that were not ok); means over the ok runs of, per
        parameter ``x``: ``x_final``, ``x_ratio`` (``x_final / x_true``),
        ``x_ref``; the coverage fractions ``x_cover68_true``,
        ``x_cover95_true``, ``x_cover68_ref``, ``x_cover95_ref`` (the share of
        the row's runs whose 68%/95% interval holds the true or the reference
        value), the mean ``nees_true`` and ``nees_ref`` (p for a calibrated
        estimator), ``w1_posterior`` if the runs have a posterior; then
        ``settling_step``, ``shape_error_mm`` (mean distance
        per grid point at the last step, mm), ``direct_mm`` (the same run
        with the true values, no assimilation), ``transfer_mm`` (on the
        transfer path), where the model has hidden targets
        (:mod:`idbench.score.targets`) ``tre_final_mm``, ``target_std_final_mm``
        and ``tre_covered_final``, then ``n_solves`` and ``wall_s_step``. Each metric
        ``m`` is followed by ``m_lo`` and ``m_hi``, the bounds of its 95%
        interval over the row's ok runs (:func:`idbench.report.intervals.interval`:
        a t interval, a bootstrap for settling steps, solves and NEES, exact
        binomial for coverage); NaN with fewer than two values.
    """
    if runs.empty:
        return pd.DataFrame()
    df, metrics = with_metrics(runs)
    axes = sweep_axes(df)
    keys = [k for k in ROW_KEYS if k in df.columns] + axes
    for k in keys:  # groupby drops NaN keys otherwise
        if df[k].isna().all():
            df[k] = df[k].fillna("")
    status = df["status"] if "status" in df else pd.Series("ok", index=df.index)
    df["_ok"] = status == "ok"
    df["_status"] = status
    df["_error"] = df["error"].fillna("") if "error" in df else ""
    ok_values = df[metrics].where(df["_ok"], np.nan)
    df[metrics] = ok_values
    rows = []
    for key, g in df.groupby(keys, dropna=False, sort=False):
        key = key if isinstance(key, tuple) else (key,)
        row: dict[str, Any] = dict(zip(keys, key, strict=True))
        row["n"] = len(g)
        row["ok"] = int(g["_ok"].sum())
        counts = g["_status"].value_counts()
        row["status"] = (
            "ok"
            if list(counts.index) == ["ok"]
            else ", ".join(f"{s} {c}" for s, c in counts.items())
        )
        errors = g.loc[~g["_ok"], "_error"].astype(str)
        row["reason"] = "; ".join(dict.fromkeys(e for e in errors if e))
        for m in metrics:
            row[m], row[f"{m}_lo"], row[f"{m}_hi"] = interval(g[m], m)
        rows.append(row)
    out = pd.DataFrame(rows)
    return out.sort_values(keys, kind="stable").reset_index(drop=True)


def with_metrics(runs: pd.DataFrame) -> tuple[pd.DataFrame, list[str]]:
    """A copy of ``runs`` with the summary's derived metrics, and their names.

    Adds ``x_ratio`` (``x_final / x_true``) and the shape errors in mm per
    grid point; the names are the summary's metric columns in their order.
    """
    df = runs.copy()
    names = parameter_names(df)
    field = is_field(df, names)
    if field:  # a map: its metrics, not one column per cell (report/maps.py)
        names = []
    for n in names:
        if f"{n}_true" in df:
            df[f"{n}_ratio"] = df[f"{n}_final"] / df[f"{n}_true"]
    _add_mm(df)
    metrics = []
    for n in names:
        metrics += [f"{n}_final", f"{n}_ratio", f"{n}_ref"]
    for n in names:
        metrics += [f"{n}_cover{c}" for c in COVERAGE]
    if field:
        metrics += [c for c in COLUMNS if c != "field_cells"]
    metrics += ["nees_true", "nees_ref", "w1_posterior"]
    metrics += ["settling_step", "shape_error_mm", "direct_mm", "transfer_mm"]
    metrics += ["tre_final_mm", "target_std_final_mm", "tre_covered_final"]
    metrics += ["heldout_final_mm"]
    metrics += ["n_solves", "wall_s_step"]
    return df, [m for m in metrics if m in df.columns]


def _add_mm(df: pd.DataFrame) -> None:
    """Shape errors in mm per grid point (the runs hold m, sum and mean)."""
    if "shape_error_mean_final" in df:
        df["shape_error_mm"] = 1000.0 * df["shape_error_mean_final"]
    if "shape_error_direct_mean" in df:
        df["direct_mm"] = 1000.0 * df["shape_error_direct_mean"]
    if {"transfer_error", "shape_error_final", "shape_error_mean_final"} <= set(df):
        # same grid on every path: points = sum / mean of the run's own error
        points = df["shape_error_final"] / df["shape_error_mean_final"]
        df["transfer_mm"] = 1000.0 * df["transfer_error"] / points


def parameter_names_of_summary(summary: pd.DataFrame) -> list[str]:
    """Parameter names in a :func:`summarise` table (``x_final`` and ``x_ref``)."""
    return [
        c[: -len("_final")]
        for c in summary.columns
        if c.endswith("_final") and c[: -len("_final")] + "_ref" in summary.columns
    ]

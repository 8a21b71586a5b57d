"""The summary's columns as people see them: headers, cells, legend, seeds.

Headers with units (:func:`headers`, abbreviated for a narrow terminal), the
cells of a :func:`idbench.report.summary.summarise` table with each mean and
its interval folded into one (``3257 +- 4`` or ``6 [4, 8]``,
:func:`summary_cells`), what the intervals are (:func:`legend`) and the
seeds a narrower interval would need (:func:`seeds_note`). Strings from
plugins are shown through :func:`idbench.core.sanitize.printable`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from idbench.core.sanitize import printable
from idbench.report.intervals import format_interval, seeds_needed
from idbench.report.summary import COVERAGE, parameter_names_of_summary

HIDDEN = ("ok",)
"""Summary columns left out of the tables for people (kept in csv and json)."""


def headers(summary: pd.DataFrame, short: bool = False) -> dict[str, str]:
    """Column headers of the summary for people, with units.

    Parameters
    ----------
    summary
        A table from :func:`summarise`.
    short
        Abbreviated headers, for a terminal narrower than the table.
    """
    fixed = {
        "scenario": ("scenario", "scen."),
        "model_nodes": ("model nodes", "nodes"),
        "mesh": ("mesh", "mesh"),
        "estimator": ("estimator", "est."),
        "n": ("n (runs)", "n"),
        "status": ("status", "status"),
        "reason": ("reason (not ok)", "reason"),
        "obs_every": ("observed every (steps)", "every"),
        "obs_points": ("markers", "M"),
        "noise": ("noise sigma", "noise"),
        "settings": ("estimator settings", "settings"),
        "settling_step": ("settling step", "settle"),
        "shape_error_mm": ("shape error (mm/pt)", "err mm"),
        "direct_mm": ("direct, true values (mm/pt)", "direct mm"),
        "transfer_mm": ("transfer error (mm/pt)", "transf mm"),
        "tre_final_mm": ("TRE, hidden targets (mm)", "TRE mm"),
        "target_std_final_mm": ("predicted target std (mm)", "tgt sd"),
        "tre_covered_final": ("target in 95% region", "tgt c95"),
        "heldout_final_mm": ("held-out markers (mm)", "held mm"),
        "nees_true": ("NEES vs true (mean)", "NEES t"),
        "nees_ref": ("NEES vs ref (mean)", "NEES r"),
        "w1_posterior": ("W1 to posterior", "W1 post"),
        "field_error": ("field error (rel. L2, log E)", "map err"),
        "field_rms_log": ("field RMS error (log E)", "map rms"),
        "inclusion_centroid_mm": ("inclusion centroid off (mm)", "incl mm"),
        "inclusion_dice": ("inclusion Dice", "Dice"),
        "field_cover95": ("cells in 95% band", "cells c95"),
        "n_solves": ("forward solves", "solves"),
        "wall_s_step": ("wall time (s/step)", "s/step"),
    }
    out = {}
    params = set(parameter_names_of_summary(summary))
    for col in summary.columns:
        if col in fixed:
            out[col] = fixed[col][short]
            continue
        cover = _coverage_header(col, params, short)
        if cover:
            out[col] = cover
            continue
        name, _, what = col.rpartition("_")
        if name in params and what == "final":
            out[col] = f"{name} final" if not short else name
        elif name in params and what == "ratio":
            out[col] = f"{name} / {name}_true" if not short else f"{name}/true"
        elif name in params and what == "ref":
            out[col] = f"{name}_ref (batch fit)" if not short else f"{name}_ref"
        else:
            out[col] = col if not short else _abbreviate(col)
    return out


def _coverage_header(col: str, params: set[str], short: bool) -> str:
    """``x 95% covers true`` (short ``x c95t``) for ``x_cover95_true``; else ''."""
    for name in params:
        for c in COVERAGE:
            if col == f"{name}_cover{c}":
                level, what = c.split("_")
                if short:
                    return f"{name} c{level}{what[0]}"
                return f"{name} {level}% covers {what}"
    return ""


def _abbreviate(name: str, width: int = 8) -> str:
    return name if len(name) <= width else name[: width - 1] + "."


def interval_columns(summary: pd.DataFrame) -> set[str]:
    """The ``m_lo`` and ``m_hi`` columns of :func:`summarise` (folded into m)."""
    cols = set(summary.columns)
    return {
        f"{c}_{b}"
        for c in cols
        if f"{c}_lo" in cols and f"{c}_hi" in cols
        for b in ("lo", "hi")
    }


def summary_cells(
    summary: pd.DataFrame,
) -> tuple[list[str], list[list[str]], list[bool]]:
    """Columns shown to people, their formatted cells and which are numeric.

    A metric's cell holds its mean and interval (``3257 +- 4``,
    :func:`idbench.report.intervals.format_interval`); strings are
    :func:`idbench.core.sanitize.printable`; a row with a single ok run says it
    has no interval in its status (unless no row has more, see
    :func:`legend`). The reason column, when any row has one, comes last.
    """
    hidden = {*HIDDEN, "reason", *interval_columns(summary)}
    cols = [c for c in summary.columns if c not in hidden]
    if "reason" in summary and summary["reason"].astype(bool).any():
        cols.append("reason")
    numeric = [pd.api.types.is_numeric_dtype(summary[c]) for c in cols]
    status = status_for_people(summary).tolist()
    rows = []
    for i, (_, r) in enumerate(summary.iterrows()):
        cells = []
        for c in cols:
            text = format_cell(r[c])
            if f"{c}_lo" in summary and f"{c}_hi" in summary:
                text = format_interval(r[c], r[f"{c}_lo"], r[f"{c}_hi"], c, text)
            if c == "status":
                text = str(status[i])
            cells.append(printable(text, join_lines=c == "reason"))
        rows.append(cells)
    return cols, rows, numeric


def status_for_people(summary: pd.DataFrame) -> pd.Series:
    """The status column, a row with one ok run saying it has no interval.

    Only when another row has one (else :func:`legend` says it once).
    """
    status = summary.get("status", pd.Series("", index=summary.index)).astype(str)
    if "ok" in summary and (summary["ok"] >= 2).any():
        one = summary["ok"] == 1
        status = status.where(~one, status + " (1 ok run: no interval)")
    return status


LEGEND = (
    "x +- h: mean and half-width of its 95% t interval over seeds; [lo, hi]: 95%"
    " bootstrap (settling step, solves, NEES) or exact binomial (coverage) interval"
)


def legend(summary: pd.DataFrame) -> str:
    """What the intervals are; or that there are none (one ok run per row)."""
    if "ok" in summary and not (summary["ok"] >= 2).any():
        return "one ok run per row: no interval (an interval needs 2 or more seeds)"
    return LEGEND


def seeds_note(summary: pd.DataFrame, relative: float = 0.01) -> list[str]:
    """Lines: the seeds a 95% interval of +-``relative`` needs on each x_final.

    From the widest t interval over the rows: its spread ``s`` (seed-to-seed
    standard deviation, recovered from the half-width) and
    :func:`idbench.report.intervals.seeds_needed`. Empty without two ok runs a row.
    """
    from scipy import stats

    lines = []
    for name in parameter_names_of_summary(summary):
        col = f"{name}_final"
        if f"{col}_lo" not in summary or "ok" not in summary:
            continue
        best: tuple[int, int, float] | None = None
        for _, r in summary.iterrows():
            k = int(r["ok"])
            half = (r[f"{col}_hi"] - r[f"{col}_lo"]) / 2.0
            if k < 2 or not np.isfinite(half) or not abs(r[col]) > 0:
                continue
            sd = half * np.sqrt(k) / stats.t.ppf(0.975, k - 1)
            need = seeds_needed(sd, relative * abs(r[col]))
            if best is None or need > best[0]:
                best = (need, k, sd / abs(r[col]))
        if best is not None:
            need, k, cv = best
            lines.append(
                f"seeds for a 95% interval of +-{relative:.0%} on {printable(col)}: "
                f"~{need} (n ~ (t s / h)^2 from the widest row: s = {100 * cv:.2g}% of "
                f"its mean over {k} seeds)"
            )
    return lines


def format_cell(v: Any) -> str:
    """A cell: whole numbers without decimals, others to 4 significant digits."""
    if isinstance(v, bool | np.bool_):
        return str(bool(v))
    if isinstance(v, int | np.integer):
        return str(v)
    if isinstance(v, float | np.floating):
        x = float(v)
        if not np.isfinite(x):
            return "-"
        if abs(x) >= 1000 or (x == round(x) and abs(x) < 1e15):
            return f"{x:.0f}"
        return f"{x:.4g}"
    return str(v)

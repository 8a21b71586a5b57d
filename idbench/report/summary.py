"""The summary of a comparison: one row per swept combination, as text or data.

:func:`summarise` groups the runs table by scenario, mesh, estimator and every
axis the sweep varied (seeds pooled, counted in ``n``); :func:`summary_text`
renders it as a plain table that is never cut, markdown, csv or json. Both
work for any model: parameters are found by their columns
(:func:`parameter_names`). Every mean carries its 95% interval over seeds
(:mod:`idbench.report.intervals`): ``x_lo`` and ``x_hi`` columns in csv and json,
``3257 +- 4`` or ``6 [4, 8]`` in the tables for people. Strings from plugins
are shown through :func:`idbench.core.sanitize.printable`.
"""

from __future__ import annotations

import textwrap
from typing import Any

import numpy as np
import pandas as pd

from idbench.core.sanitize import markdown_cell, printable
from idbench.report.intervals import format_interval, interval, seeds_needed

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
    described += [f"{n}_true" for n in parameter_names(runs) if f"{n}_true" in cols]
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
    for n in names:
        if f"{n}_true" in df:
            df[f"{n}_ratio"] = df[f"{n}_final"] / df[f"{n}_true"]
    _add_mm(df)
    metrics = []
    for n in names:
        metrics += [f"{n}_final", f"{n}_ratio", f"{n}_ref"]
    for n in names:
        metrics += [f"{n}_cover{c}" for c in COVERAGE]
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


FORMATS = ("table", "markdown", "csv", "json")
"""What :func:`summary_text` writes."""

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


def parameter_names_of_summary(summary: pd.DataFrame) -> list[str]:
    """Parameter names in a :func:`summarise` table (``x_final`` and ``x_ref``)."""
    return [
        c[: -len("_final")]
        for c in summary.columns
        if c.endswith("_final") and c[: -len("_final")] + "_ref" in summary.columns
    ]


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


def _cells(summary: pd.DataFrame) -> tuple[list[str], list[list[str]], list[bool]]:
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


TITLE = "idbench compare: means over the ok runs of each row (n: runs, one a seed)"

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


def summary_text(
    runs: pd.DataFrame, fmt: str = "table", width: int | None = None
) -> str:
    """The summary of ``runs`` as text that never cuts a value.

    Parameters
    ----------
    runs
        The runs table of a comparison.
    fmt
        ``table`` (aligned plain text, headers with units), ``markdown``,
        ``csv`` or ``json`` (records; machine column names, NaN as null).
    width
        For ``table`` on a terminal: its width in characters. Headers are then
        abbreviated, a table wider than that is split into blocks of columns
        (each repeating the row keys), and reasons become footnotes; values
        are never cut. ``None`` (a pipe or file): one table, full headers.
    """
    if fmt not in FORMATS:
        raise ValueError(f"format {fmt!r}: choose from {', '.join(FORMATS)}")
    summary = summarise(runs)
    if fmt == "csv":  # strings shown as text: a csv may be printed to a terminal
        shown = summary.map(lambda v: printable(v) if isinstance(v, str) else v)
        shown.columns = [printable(c) for c in summary.columns]
        return str(shown.to_csv(index=False))
    if fmt == "json":
        return str(summary.to_json(orient="records", indent=1))
    if summary.empty:
        return "(no runs)"
    flags = flagged_lines(runs)
    if fmt == "markdown":
        text = _markdown(summary, headers(summary))
        flags = flagged_lines(runs, markdown=True)
        return "\n\n".join([text, "\n".join(flags)]) if flags else text
    cols, rows, numeric = _cells(summary)
    if width is None:
        table = _aligned(cols, rows, numeric, headers(summary))
        return "\n".join([TITLE, *table, legend(summary), *seeds_note(summary), *flags])
    names = headers(summary, short=True)
    notes: list[str] = []
    if "reason" in cols:
        i, s = cols.index("reason"), cols.index("status")
        for r in rows:
            if r[i]:
                if r[i] not in notes:
                    notes.append(r[i])
                r[s] += f" [{notes.index(r[i]) + 1}]"
            del r[i]
        del cols[i], numeric[i]
    keys = {*ROW_KEYS, *sweep_axes(runs)}
    n_keys = sum(1 for c in cols if c in keys)
    lines = [TITLE]
    lines += text_blocks(cols, rows, numeric, names, n_keys, width)
    lines += textwrap.wrap(legend(summary), width=max(width, 40))
    for j, note in enumerate(notes, start=1):
        lines += textwrap.wrap(
            f"[{j}] {note}", width=max(width, 40), subsequent_indent="    "
        )
    for line in seeds_note(summary):
        lines += textwrap.wrap(line, width=max(width, 40), subsequent_indent="    ")
    lines += flags
    return "\n".join(lines).rstrip()


def flagged_lines(runs: pd.DataFrame, markdown: bool = False) -> list[str]:
    """Lines naming the runs whose ``warning`` column flags them (none: []).

    Plugin-supplied names are shown as text (:mod:`idbench.core.sanitize`), escaped for
    markdown with ``markdown=True``.
    """
    if "warning" not in runs or runs.empty:
        return []
    text = runs["warning"].fillna("").astype(str)
    flagged = runs[text != ""]
    if flagged.empty:
        return []
    lines = [
        f"flagged: {len(flagged)} run(s) whose result may mean nothing "
        "(runs.parquet, column warning):"
    ]
    keys = [k for k in ("scenario", "mesh", "estimator") if k in runs]
    for key, g in flagged.groupby([*(flagged[k] for k in keys), text[text != ""]]):
        *names, why = key
        shown = markdown_cell if markdown else printable
        lines.append(f"  {shown(' '.join(map(str, names)))} ({len(g)} run(s)): {why}")
    return lines


def _aligned(
    cols: list[str], rows: list[list[str]], numeric: list[bool], names: dict[str, str]
) -> list[str]:
    """Lines of a plain table: a header, a rule, the rows; numbers right-aligned."""
    head = [printable(names.get(c, c)) for c in cols]
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]

    def line(cells: list[str]) -> str:
        parts = [
            c.rjust(w) if num else c.ljust(w)
            for c, w, num in zip(cells, widths, numeric, strict=True)
        ]
        return "  ".join(parts).rstrip()

    rule = "  ".join("-" * w for w in widths)
    return [line(head), rule, *(line(r) for r in rows)]


def text_blocks(
    cols: list[str],
    rows: list[list[str]],
    numeric: list[bool],
    names: dict[str, str],
    n_keys: int,
    width: int | None,
) -> list[str]:
    """An aligned text table split in blocks of columns that fit ``width``.

    Parameters
    ----------
    cols, rows
        Column names and the rows' cells (strings).
    numeric
        Per column: right-aligned (numbers) or not.
    names
        Header to print per column name (the name itself if absent).
    n_keys
        The first ``n_keys`` columns identify a row: each block repeats them.
    width
        Characters a line may take; None: one block, however wide.

    Returns
    -------
    list of str
        The lines, each block followed by an empty line (not so the one block
        of ``width=None``).
    """
    if width is None:
        return _aligned(cols, rows, numeric, names)
    lines: list[str] = []
    for block in _blocks(cols, rows, names, n_keys, width):
        lines += _aligned(
            [cols[j] for j in block],
            [[r[j] for j in block] for r in rows],
            [numeric[j] for j in block],
            names,
        )
        lines.append("")
    return lines


def _blocks(
    cols: list[str],
    rows: list[list[str]],
    names: dict[str, str],
    n_keys: int,
    width: int,
) -> list[list[int]]:
    """Column indices of each block: the key columns, then what fits in width."""
    need = [
        max(len(printable(names.get(c, c))), *(len(r[i]) for r in rows)) + 2
        for i, c in enumerate(cols)
    ]
    keys = list(range(n_keys))
    base = sum(need[i] for i in keys)
    blocks: list[list[int]] = []
    current: list[int] = []
    used = base
    for i in range(n_keys, len(cols)):
        if current and used + need[i] > width:
            blocks.append(keys + current)
            current, used = [], base
        current.append(i)
        used += need[i]
    blocks.append(keys + current)
    return blocks


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


def _markdown(df: pd.DataFrame, names: dict[str, str] | None = None) -> str:
    """A markdown table of ``df`` (never truncated), headers renamed by ``names``.

    With ``names``, ``df`` is a :func:`summarise` table, shown as in the text
    table (:func:`_cells`: intervals folded into their means, the reason
    last). Every cell and header goes through
    :func:`idbench.core.sanitize.markdown_cell`: no raw HTML, no broken row.
    """
    if df.empty:
        return "(no runs)"
    if names:
        cols, rows, _ = _cells(df)
    else:
        cols = [str(c) for c in df.columns]
        rows = [[format_cell(v) for v in r] for r in df.itertuples(index=False)]
    names = names or {}
    head = "| " + " | ".join(markdown_cell(names.get(c, c)) for c in cols) + " |"
    rule = "|" + "---|" * len(cols)
    body = [
        "| " + " | ".join(markdown_cell(v, join_lines=True) for v in row) + " |"
        for row in rows
    ]
    return "\n".join([head, rule, *body])

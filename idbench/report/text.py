"""The summary as text: a plain table that is never cut, markdown, csv or json.

:func:`summary_text` renders :func:`idbench.report.summary.summarise` with
the columns of :mod:`idbench.report.columns`; a table wider than the
terminal is split in blocks of columns (:func:`text_blocks`). The runs a
warning flags are listed after it (:func:`flagged_lines`), then estimators
that disagree on the same data (:func:`idbench.report.caveats.disagreements`).
Strings from plugins are shown through :func:`idbench.core.sanitize.printable`
(in markdown, :func:`idbench.core.sanitize.markdown_cell`).
"""

from __future__ import annotations

import textwrap

import pandas as pd

from idbench.core.sanitize import markdown_cell, printable
from idbench.report.caveats import disagreements
from idbench.report.columns import (
    format_cell,
    headers,
    legend,
    seeds_note,
    summary_cells,
)
from idbench.report.summary import ROW_KEYS, summarise, sweep_axes

FORMATS = ("table", "markdown", "csv", "json")
"""What :func:`summary_text` writes."""


TITLE = "idbench compare: means over the ok runs of each row (n: runs, one a seed)"


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
    flags = flagged_lines(runs) + disagreements(runs)
    if fmt == "markdown":
        text = markdown_table(summary, headers(summary))
        flags = flagged_lines(runs, markdown=True) + disagreements(runs, True)
        return "\n\n".join([text, "\n".join(flags)]) if flags else text
    cols, rows, numeric = summary_cells(summary)
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
    for line in [*seeds_note(summary), *flags]:
        lines += textwrap.wrap(line, width=max(width, 40), subsequent_indent="    ")
    return "\n".join(lines).rstrip()


LOAD_TOLERANCE = 0.02
"""A run's load figure is flagged when its ratio to the truth's is off 1 by more."""


def flagged_lines(runs: pd.DataFrame, markdown: bool = False) -> list[str]:
    """Lines naming the runs whose ``warning`` column flags them (none: []).

    Then the rows whose load is not the truth's (:func:`load_lines`).
    Plugin-supplied names are shown as text (:mod:`idbench.core.sanitize`), escaped for
    markdown with ``markdown=True``.
    """
    return _warning_lines(runs, markdown) + load_lines(runs, markdown)


def load_lines(runs: pd.DataFrame, markdown: bool = False) -> list[str]:
    """Lines naming the (scenario, mesh) whose load differs from the truth's.

    A ``load_NAME_ratio`` column (model over truth, see
    :func:`idbench.run.rows.load_columns`) off 1 by more than
    :data:`LOAD_TOLERANCE` flags its rows; each line gives the figures that
    are off, as ratios (the same for every estimator and seed of a mesh).
    """
    cols = [c for c in runs.columns if c.startswith("load_") and c.endswith("_ratio")]
    if not cols or runs.empty:
        return []
    ratios = runs[cols].apply(pd.to_numeric, errors="coerce")
    off = (ratios - 1).abs() > LOAD_TOLERANCE
    flagged = runs[off.any(axis=1)]
    if flagged.empty:
        return []
    keys = [k for k in ("scenario", "mesh") if k in runs]
    order = [k for k in ("scenario", "model_nodes", "mesh") if k in runs]
    flagged = flagged.sort_values(order, kind="stable") if order else flagged
    groups = list(
        flagged.groupby([flagged[k].astype(str) for k in keys], sort=False)
    )
    lines = [
        f"load: {len(groups)} row(s) whose model's load differs from the truth's by "
        f"more than {LOAD_TOLERANCE:.0%} (runs.parquet, columns load_*_ratio; "
        "model / truth):"
    ]
    shown = markdown_cell if markdown else printable
    for key, g in groups:
        names = key if isinstance(key, tuple) else (key,)
        mean = ratios.loc[g.index].mean()
        parts = [
            f"{c[len('load_') : -len('_ratio')]} {mean[c]:.3g}"
            for c in cols
            if abs(mean[c] - 1) > LOAD_TOLERANCE
        ]
        lines.append(f"  {shown(' '.join(map(str, names)))}: {', '.join(parts)}")
    return lines


def _warning_lines(runs: pd.DataFrame, markdown: bool = False) -> list[str]:
    """:func:`flagged_lines` of the ``warning`` column."""
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


def markdown_table(df: pd.DataFrame, names: dict[str, str] | None = None) -> str:
    """A markdown table of ``df`` (never truncated), headers renamed by ``names``.

    With ``names``, ``df`` is a :func:`summarise` table, shown as in the text
    table (:func:`summary_cells`: intervals folded into their means, the reason
    last). Every cell and header goes through
    :func:`idbench.core.sanitize.markdown_cell`: no raw HTML, no broken row.
    """
    if df.empty:
        return "(no runs)"
    if names:
        cols, rows, _ = summary_cells(df)
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

"""Paired differences: each estimator (or mesh) against one, seed by seed.

The noise of a seed is drawn once and shared by every estimator, mesh,
noise level and spacing of a sweep (common random numbers), so two runs
that differ only in the estimator saw the same data. Their difference is
free of the seed-to-seed spread they share, and its interval is far
narrower than the difference of two independent means would allow.
:func:`paired_differences` pairs runs on everything but the estimator (or
the mesh), takes the difference of each metric per pair and its mean and 95%
interval over the pairs of each row (:func:`idbench.report.intervals.interval`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import pandas as pd

from idbench.core.sanitize import markdown_cell, printable
from idbench.report.columns import format_cell, headers
from idbench.report.intervals import excludes_zero, format_interval, interval
from idbench.report.summary import (
    ROW_KEYS,
    SEED_COLUMNS,
    parameter_names,
    sweep_axes,
    with_metrics,
)
from idbench.report.text import text_blocks

BY = {"estimator": ("settings",), "mesh": ("model_nodes",)}
"""What a comparison varies, and the columns that go with it (never paired on)."""

MARK = "*"
"""Appended to a difference whose 95% interval excludes 0."""


@dataclass
class Paired:
    """Paired differences against one estimator or mesh.

    Attributes
    ----------
    by
        ``estimator`` or ``mesh``.
    versus
        The estimator (mesh) subtracted.
    table
        One row per other estimator (mesh) and row of the summary it shares:
        the keys, ``other``, ``pairs`` (runs paired, both ok), and per
        metric ``m`` the mean difference (other - versus) and ``m_lo``,
        ``m_hi``.
    metrics
        The metrics in the table.
    identical
        Metrics equal in every pair (left out of the table).
    paired_on
        The columns two runs of a pair share.
    varying
        Those of ``paired_on`` that take more than one value in the runs.
    """

    by: str
    versus: str
    table: pd.DataFrame
    metrics: list[str] = field(default_factory=list)
    identical: list[str] = field(default_factory=list)
    paired_on: list[str] = field(default_factory=list)
    varying: list[str] = field(default_factory=list)


def paired_differences(
    runs: pd.DataFrame, versus: str, by: str = "estimator"
) -> Paired:
    """Differences of every metric between each other ``by`` and ``versus``.

    Two ok runs form a pair when they agree on every description column
    (scenario, mesh, seed, noise, obs_every, markers, true values, prior...)
    except ``by`` and what goes with it (an estimator's ``settings``, a
    mesh's ``model_nodes``). The rows are those of the summary without
    ``by``; an estimator whose settings were swept is one ``other`` per
    setting.

    Raises
    ------
    ValueError
        ``versus`` did not run (names what did), or is not one run per pair
        (its settings were swept).
    """
    if by not in BY:
        raise ValueError(f"pair by {by!r}: choose from {', '.join(BY)}")
    if runs.empty or by not in runs:
        raise ValueError("no runs to pair")
    known = sorted(map(str, runs[by].unique()))
    if versus not in known:
        raise ValueError(
            f"--versus{'' if by == 'estimator' else '-mesh'} {versus!r} did not run;"
            f" ran: {', '.join(printable(k) for k in known)}"
        )
    df, metrics = with_metrics(runs)
    if "status" in df:
        df = df[df["status"] == "ok"]
    cols = list(runs.columns)
    described = cols[: cols.index("status")] if "status" in cols else []
    described += [  # the true values (E_true), not metrics against them (nees_true)
        c
        for c in (f"{n}_true" for n in parameter_names(runs))
        if c in cols and c not in described
    ]
    apart = {by, *BY[by], "run_id"}
    paired_on = [c for c in described if c not in apart and c not in metrics]
    df = df.assign(
        _pair=(  # str of each cell: a NaN (a recording's truth nodes) is "nan"
            df[paired_on].map(str).agg("\x1f".join, axis=1) if paired_on else ""
        ),
        other=df[by].astype(str),
    )
    if by == "estimator" and "settings" in df:
        swept = df.groupby("estimator")["settings"].transform("nunique") > 1
        df.loc[swept, "other"] += " " + df.loc[swept, "settings"].astype(str)
    ref = df[df[by].astype(str) == versus]
    if ref["_pair"].duplicated().any():
        raise ValueError(
            f"{printable(versus)} ran more than once with the same other settings"
            f" (its {' or '.join(BY[by])} were swept): pairing needs one run each"
        )
    others = df[df[by].astype(str) != versus]
    both = others.merge(ref[["_pair", *metrics]], on="_pair", suffixes=("", "__versus"))
    skip = {by, *BY[by], *(set(SEED_COLUMNS) - {"model_nodes"}), "seed"}
    keys = [k for k in ROW_KEYS if k in both and k not in skip]
    keys += [a for a in sweep_axes(runs) if a in both and a not in skip]
    keys.append("other")
    for m in metrics:
        both[m] = both[m] - both[f"{m}__versus"]
    identical = [
        m for m in metrics if both[m].notna().any() and (both[m].dropna() == 0).all()
    ]
    shown = [m for m in metrics if both[m].notna().any() and m not in identical]
    rows: list[dict[str, Any]] = []
    for key, g in both.groupby(keys, dropna=False, sort=True):
        row: dict[str, Any] = dict(zip(keys, key, strict=True))
        row["pairs"] = len(g)
        for m in shown:
            row[m], row[f"{m}_lo"], row[f"{m}_hi"] = interval(g[m], m, paired=True)
        rows.append(row)
    table = pd.DataFrame(rows, columns=[*keys, "pairs"] if not rows else None)
    varying = [c for c in paired_on if runs[c].astype(str).nunique() > 1]
    return Paired(by, versus, table, shown, identical, paired_on, varying)


def _cells(p: Paired) -> tuple[list[str], list[list[str]], list[bool]]:
    """Columns, cells (``-12 +- 3 *``) and which are numeric, for people."""
    t = p.table
    cols = [c for c in t.columns if not c.endswith(("_lo", "_hi"))]
    numeric = [c in p.metrics or c in ("pairs", "model_nodes") for c in cols]
    rows = []
    for _, r in t.iterrows():
        cells = []
        for c in cols:
            text = format_cell(r[c])
            if c in p.metrics:
                lo, hi = r[f"{c}_lo"], r[f"{c}_hi"]
                text = format_interval(r[c], lo, hi, c, text)
                text += f" {MARK}" if excludes_zero(lo, hi) else ""
            cells.append(printable(text))
        rows.append(cells)
    return cols, rows, numeric


def _names(p: Paired) -> dict[str, str]:
    cols = [*p.table.columns, *p.identical]
    names = headers(pd.DataFrame(columns=cols))
    names["other"] = p.by
    names["pairs"] = "pairs (seeds)"
    return names


def title(p: Paired) -> list[str]:
    """What the table holds, for people (a list of lines)."""
    shared = ", ".join(printable(c) for c in p.varying) or "no other setting"
    lines = [
        f"paired differences: each {p.by} minus {printable(p.versus)}, mean over the"
        f" pairs of ok runs that differ only in the {p.by} (same {shared}, ...);"
        " 95% intervals (t, or bootstrap for settling step, solves, NEES and"
        f" coverage); {MARK}: the interval excludes 0",
    ]
    if p.identical:
        lines.append("equal in every pair (left out): " + ", ".join(p.identical))
    return lines


def paired_text(p: Paired, width: int | None = None) -> str:
    """The paired table as aligned plain text (split in blocks to fit ``width``)."""
    if p.table.empty:
        return "\n".join([*title(p), "(no pairs: no other run shares its settings)"])
    cols, rows, numeric = _cells(p)
    names = _names(p)
    n_keys = sum(1 for c in cols if c not in p.metrics)
    lines = title(p)
    lines += text_blocks(cols, rows, numeric, names, n_keys, width)
    return "\n".join(lines).rstrip()


def paired_markdown(p: Paired) -> str:
    """The paired table as a markdown section (title, then the table)."""
    head = [f"## Paired differences against {markdown_cell(p.versus)} ({p.by})", ""]
    head += [markdown_cell(line) for line in title(p)]
    if p.table.empty:
        return "\n".join([*head, "", "(no pairs)"])
    cols, rows, _ = _cells(p)
    names = _names(p)
    table = [
        "| " + " | ".join(markdown_cell(names.get(c, c)) for c in cols) + " |",
        "|" + "---|" * len(cols),
        *("| " + " | ".join(markdown_cell(v) for v in r) + " |" for r in rows),
    ]
    return "\n".join([*head, "", *table])


def paired_html(p: Paired) -> str:
    """The paired table as an HTML section (escaped)."""
    import html

    def esc(v: Any) -> str:
        return html.escape(printable(v))

    parts = [f"<h2>Paired differences against {esc(p.versus)} ({esc(p.by)})</h2>"]
    parts += [f"<p>{esc(line)}</p>" for line in title(p)]
    if p.table.empty:
        return "\n".join([*parts, "<p>(no pairs)</p>"])
    cols, rows, numeric = _cells(p)
    names = _names(p)
    head = "".join(f'<th scope="col">{esc(names.get(c, c))}</th>' for c in cols)
    num = ' class="num"'
    body = "".join(
        "<tr>"
        + "".join(
            f"<td{num if is_num else ''}>{esc(v)}</td>"
            for v, is_num in zip(r, numeric, strict=True)
        )
        + "</tr>"
        for r in rows
    )
    parts.append(
        f'<div class="scroll"><table class="paired"><thead><tr>{head}</tr></thead>'
        f"<tbody>{body}</tbody></table></div>"
    )
    return "\n".join(parts)

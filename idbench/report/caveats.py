"""What a reader must know before believing a comparison's numbers.

:func:`disagreements`: estimators that, on the same data, differ by far more
than their own intervals say they could (at least one of them is wrong, or
both), a line of the summary (:func:`idbench.report.text.summary_text`);
:func:`incomplete_traces`: ok runs whose traces lack steps;
:func:`caveat_lines`: these and, where a run is flagged inconsistent, that
its interval is not to be believed, for report.md and report.html after
the runs a warning flags (:func:`idbench.report.text.flagged_lines`).
Strings from plugins are shown through :mod:`idbench.core.sanitize`.
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
import pandas as pd

from idbench.core.sanitize import markdown_cell, printable
from idbench.report.summary import SEED_COLUMNS, parameter_names
from idbench.score.metrics import INCONSISTENT

DISAGREE = 5.0
"""Two estimates disagree when they differ by more than this many combined
standard deviations, sqrt(std_a^2 + std_b^2): far more than their 95%
intervals allow (1.96 each)."""

NOT_TO_BE_BELIEVED = (
    f"A run flagged {INCONSISTENT} has innovations its filter did not expect "
    "(its NIS outside the 95% chi-square band): its std, its intervals and their "
    "coverage are not to be believed, whatever its estimate."
)


def data_columns(runs: pd.DataFrame) -> list[str]:
    """The columns that say which data a run had (all but who estimated it).

    The description columns (those before ``status``) but the run id, the
    estimator, its settings and the node counts.
    """
    if "status" not in runs:
        return []
    cols = list(runs.columns)
    skip = {*SEED_COLUMNS, "estimator", "settings"} - {"seed"}
    return [c for c in cols[: cols.index("status")] if c not in skip]


def disagreements(runs: pd.DataFrame, markdown: bool = False) -> list[str]:
    """One line naming the estimators that disagree on the same data (none: []).

    Per data set (:func:`data_columns`) and parameter ``x``, two ok runs
    disagree when their ``x_final`` differ by more than :data:`DISAGREE`
    combined ``x_std_final``; the line names each such pair with its
    scenario and mesh, in how many of their common data sets they disagree
    and by how much at most.
    """
    if runs.empty or "status" not in runs:
        return []
    ok = runs[runs["status"] == "ok"]
    keys = data_columns(ok)
    names = [n for n in parameter_names(ok) if f"{n}_std_final" in ok]
    if not keys or not names or ok.empty:
        return []
    found: dict[tuple[str, str, str, str], list[Any]] = {}
    for _, g in ok.groupby(keys, dropna=False, sort=True):
        for (_, a), (_, b) in itertools.combinations(g.iterrows(), 2):
            first, second = sorted((_label(a), _label(b)))
            where = (str(a.get("scenario", "")), str(a.get("mesh", "")))
            worst = _worst(a, b, names)
            if worst is None:
                continue
            entry = found.setdefault((*where, first, second), [0, 0, 0.0, ""])
            entry[1] += 1
            if worst[0] > DISAGREE:
                entry[0] += 1
                if worst[0] > entry[2]:
                    entry[2], entry[3] = worst
    shown = markdown_cell if markdown else printable
    parts = [
        shown(f"{a} and {b} on {scenario} {mesh}")
        + f" ({n} of {total} data sets, up to {z:.0f} std in {shown(name)})"
        for (scenario, mesh, a, b), (n, total, z, name) in found.items()
        if n
    ]
    if not parts:
        return []
    return [
        "disagree: on the same data these estimators differ by more than "
        f"{DISAGREE:g} times their combined std (far beyond their intervals; "
        f"at least one is wrong): {'; '.join(parts)}"
    ]


def _label(run: pd.Series) -> str:
    """An estimator's name, with its settings where it has any."""
    settings = str(run.get("settings", "{}"))
    extra = f" {settings}" if settings not in ("{}", "", "nan") else ""
    return f"{run['estimator']}{extra}"


def _worst(a: pd.Series, b: pd.Series, names: list[str]) -> tuple[float, str] | None:
    """The largest |x_a - x_b| / sqrt(s_a^2 + s_b^2) over the parameters, and x."""
    best: tuple[float, str] | None = None
    for n in names:
        d = float(a[f"{n}_final"]) - float(b[f"{n}_final"])
        s = float(np.hypot(a[f"{n}_std_final"], b[f"{n}_std_final"]))
        if not (np.isfinite(d) and np.isfinite(s) and s > 0):
            continue
        z = abs(d) / s
        if best is None or z > best[0]:
            best = (z, n)
    return best


def incomplete_traces(
    runs: pd.DataFrame, traces: pd.DataFrame, markdown: bool = False
) -> list[str]:
    """One line on the ok runs whose traces lack steps (none: []).

    An ok run has one traces row per step 1..``steps``; a run with fewer
    (or none: no ``traces.parquet``) is named, with the steps it has.
    """
    if runs.empty or "status" not in runs or "steps" not in runs:
        return []
    ok = runs[runs["status"] == "ok"]
    if traces.empty or "run_id" not in traces or "step" not in traces:
        have = pd.Series(dtype=int)
    else:
        have = traces.groupby("run_id")["step"].nunique()
    short = []
    for _, r in ok.iterrows():
        n = int(have.get(r["run_id"], 0))
        if n < int(r["steps"]):
            short.append((r, n))
    if not short:
        return []
    shown = markdown_cell if markdown else printable
    named = ", ".join(
        shown(f"{r.get('estimator', '')} {r.get('scenario', '')} {r.get('mesh', '')} "
              f"seed {r.get('seed', '')}")
        + f" ({n} of {int(r['steps'])} steps)"
        for r, n in short[:5]
    )  # fmt: skip
    more = f" and {len(short) - 5} more" if len(short) > 5 else ""
    return [
        f"traces incomplete: {len(short)} ok run(s) have traces for fewer steps "
        f"than they ran (traces.parquet): {named}{more}; their traces and "
        "figures over the steps are not the whole run"
    ]


def caveat_lines(
    runs: pd.DataFrame, traces: pd.DataFrame, markdown: bool = False
) -> list[str]:
    """What an inconsistent flag means (if a run has it), disagreements, traces."""
    lines = []
    warned = runs["warning"].fillna("").astype(str) if "warning" in runs else None
    if warned is not None and warned.str.contains(INCONSISTENT).any():
        lines.append(NOT_TO_BE_BELIEVED)
    return [
        *lines,
        *disagreements(runs, markdown),
        *incomplete_traces(runs, traces, markdown),
    ]

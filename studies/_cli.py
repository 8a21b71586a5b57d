"""What the study scripts share: the command line (``--quick``, ``--out``,
progress), the study's comparison with its quick overrides and its runs, the
main block."""

from __future__ import annotations

import argparse
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd

from idbench import CompareConfig, compare


def parser(doc: str, out: str) -> argparse.ArgumentParser:
    """Arguments of a study (add more before ``parse_args``); logs progress.

    Parameters
    ----------
    doc
        The script's module docstring; its first line describes the script.
    out
        Default results folder, e.g. ``"results/fig2"``.
    """
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    p = argparse.ArgumentParser(description=doc.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="small meshes, seconds")
    p.add_argument("--out", type=Path, default=Path(out), help=f"default {out}")
    return p


QUICK: dict[str, Any] = {
    "meshes": ("4x1x1", "8x2x2", "12x3x3"),
    "truth_mesh": "24x4x4",
    "seeds": 1,
    "steps": 6,
}
"""The quick size of a beam study over resolutions: three small meshes, a
small truth, one seed, six load steps (seconds)."""


def config(
    quick: bool, full: dict[str, Any], small: dict[str, Any], **settings: Any
) -> CompareConfig:
    """The comparison ``full`` + ``settings``, with ``small`` on top if ``quick``."""
    return CompareConfig(**{**full, **settings, **(small if quick else {})})


def runs(
    config: CompareConfig, out: str | Path | None, **options: Any
) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """Run the comparison (:func:`idbench.compare` with ``options``).

    Returns
    -------
    tuple
        All runs, the runs with status ``ok``, and the per-step traces.
    """
    table, traces = compare(config, out, **options)
    return table, table[table["status"] == "ok"], traces


def report(folder: str | Path | None, quick: bool) -> None:
    """Write ``folder``'s report (report.html with its 3D view, report.md).

    For a full run that keeps its comparison in ``folder``
    (:func:`idbench.report.write.write_report`); nothing for a quick run or
    without a folder.
    """
    if folder is None or quick:
        return
    from idbench.report.write import write_report

    write_report(Path(folder))


def over_seeds(
    frame: pd.DataFrame,
    by: list[str],
    *,
    sd: tuple[str, ...] = (),
    first: tuple[str, ...] = (),
    count: str | None = None,
    sort: bool = True,
    **columns: str,
) -> pd.DataFrame:
    """A study's table: one row per group of ``by`` (a setting and its seeds).

    Parameters
    ----------
    frame
        Runs (or traces), one row per seed of each setting.
    by
        The columns that make a setting; they lead the table.
    sd
        The names in ``columns`` that also get ``NAME_sd``, the standard
        deviation over the group.
    first
        Columns constant in a group, kept as they are.
    count
        If given, the name of a column with the group's size.
    sort
        Sort the groups (else in order of appearance).
    **columns
        ``NAME=COLUMN``: the mean of ``COLUMN`` over the group, as ``NAME``.
    """
    agg: dict[str, tuple[str, str]] = {}
    for name, column in columns.items():
        agg[name] = (column, "mean")
        if name in sd:
            agg[f"{name}_sd"] = (column, "std")
    agg.update({column: (column, "first") for column in first})
    if count is not None:
        agg[count] = (by[0], "size")
    return frame.groupby(by, sort=sort).agg(**agg).reset_index()


DOCS_DATA = Path(__file__).resolve().parent.parent / "docs" / "results" / "data"
"""Where a full run writes the numbers its results page shows."""


def docs_data(name: str, table: pd.DataFrame) -> Path:
    """Write ``table`` to ``docs/results/data/<name>.csv`` (full runs only).

    The results page shows it through the study's ``markdown(table)``;
    ``tests/docs/test_results.py`` fails while the page and the file differ
    (``python tests/docs/test_results.py`` rewrites the page's table).
    """
    DOCS_DATA.mkdir(parents=True, exist_ok=True)
    path = DOCS_DATA / f"{name}.csv"
    table.to_csv(path, index=False)
    return path


def show(table: pd.DataFrame) -> None:
    """Print the study's table, all rows, no index."""
    print(table.to_string(index=False))


def main(
    doc: str,
    out: str,
    compute: Callable[..., pd.DataFrame],
    plot: Callable[[pd.DataFrame, Path], None],
    name: str,
    *,
    printed: Callable[[pd.DataFrame], None] = show,
    csv: bool = False,
    options: dict[str, dict[str, Any]] | None = None,
) -> None:
    """Run a study from its command line: compute, print, save, plot.

    Parameters
    ----------
    doc, out
        As for :func:`parser`.
    compute
        The study's ``compute(quick, out, **options)``.
    plot
        The study's ``plot(table, path)``; the figure is ``<out>/<name>.png``.
    name
        The study's file name (without ``.py``).
    printed
        Prints the table (default :func:`show`).
    csv
        Also write the table to ``<out>/<name>.csv``.
    options
        Further arguments of the study: ``{name: add_argument keywords}``
        (``--name`` on the command line), passed to ``compute`` by name.
    """
    p = parser(doc, out)
    for option, keywords in (options or {}).items():
        p.add_argument(f"--{option}", **keywords)
    args = p.parse_args()
    extra = {option: getattr(args, option) for option in options or {}}
    table = compute(args.quick, args.out, **extra)
    printed(table)
    if csv:
        args.out.mkdir(parents=True, exist_ok=True)
        table.to_csv(args.out / f"{name}.csv", index=False)
    plot(table, args.out / f"{name}.png")

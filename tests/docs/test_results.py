"""Result pages show the numbers their studies wrote.

A table on a results page preceded by ``<!-- table: data/NAME.csv by
studies/STUDY.py FUNCTION -->`` must equal ``FUNCTION(pandas.read_csv(...))``
of that study: the study writes the CSV in full mode
(``studies/_cli.py:docs_data``) and formats it with its own function, so a
rerun that changes a number fails here until the page shows it.

``python tests/docs/test_results.py`` rewrites every such table from its file.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"
MARK = re.compile(
    r"<!-- table: (?P<data>\S+) by (?P<study>studies/\w+\.py) (?P<fn>\w+) -->"
)


def _study(path: str):
    sys.path.insert(0, str(ROOT / "studies"))  # studies import their _cli
    name = f"docs_study_{Path(path).stem}"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, ROOT / path)
        module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
        sys.modules[name] = module
        spec.loader.exec_module(module)  # type: ignore[union-attr]
    return sys.modules[name]


def tables(page: Path) -> list[tuple[re.Match[str], int, int]]:
    """Each marked table: its marker and the line span [start, end) of its rows."""
    lines = page.read_text(encoding="utf-8").splitlines()
    out = []
    for i, line in enumerate(lines):
        m = MARK.search(line)
        if not m:
            continue
        start = i + 1
        while start < len(lines) and not lines[start].strip():
            start += 1
        end = start
        while end < len(lines) and lines[end].startswith("|"):
            end += 1
        out.append((m, start, end))
    return out


def expected(m: re.Match[str]) -> str:
    """The table the study's function makes of the data file."""
    table = pd.read_csv(RESULTS / m.group("data"))
    return getattr(_study(m.group("study")), m.group("fn"))(table)


def _cases() -> list:
    out = []
    for page in sorted(RESULTS.glob("*.md")):
        for m, start, end in tables(page):
            name = f"{page.name}:{m.group('data')}"
            out.append(pytest.param(page, m, start, end, id=name))
    return out


@pytest.mark.parametrize(("page", "mark", "start", "end"), _cases())
def test_page_table_is_its_data_file(page: Path, mark, start: int, end: int) -> None:
    shown = page.read_text(encoding="utf-8").splitlines()[start:end]
    want = expected(mark).rstrip("\n").splitlines()
    assert shown == want, (
        f"{page.name}: the table after {mark.group(0)} differs from its data file; "
        "run `python tests/docs/test_results.py` to rewrite it:\n" + "\n".join(want)
    )


def test_pages_with_data_files() -> None:
    marked = {
        m.group("data") for page in RESULTS.glob("*.md") for m, _, _ in tables(page)
    }
    files = {f"data/{p.name}" for p in (RESULTS / "data").glob("*.csv")}
    assert marked == files, "every data file is shown by a page, and only those"
    assert len(marked) >= 3


def test_a_changed_number_fails() -> None:
    (m, start, _) = tables(RESULTS / "organ-frontier.md")[0]
    lines = (RESULTS / "organ-frontier.md").read_text(encoding="utf-8").splitlines()
    row = lines[start + 2]
    changed = re.sub(r"\| (\d+(\.\d+)?) \|", "| 1 |", row, count=1)
    assert changed != row
    assert changed not in expected(m).splitlines()


def rewrite() -> None:
    """Rewrite every marked table of docs/results/*.md from its data file."""
    for page in sorted(RESULTS.glob("*.md")):
        lines = page.read_text(encoding="utf-8").splitlines()
        for m, start, end in reversed(tables(page)):
            lines[start:end] = expected(m).rstrip("\n").splitlines()
        page.write_text("\n".join(lines) + "\n", encoding="utf-8")


if __name__ == "__main__":
    rewrite()

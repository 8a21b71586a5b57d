"""Every column a comparison writes is documented in docs/reference/outputs.md."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from idbench import CompareConfig, compare

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "reference" / "outputs.md"


def documented(column: str, text: str, parameters: tuple[str, ...]) -> bool:
    """Whether ``column`` (a parameter's columns as the page's ``E_*``) is named."""
    for name in parameters:  # E_region0_final is documented as E_final
        if column == name or column.startswith(f"{name}_"):
            column = "E" + column[len(name):]
            break
    return re.search(rf"(?<![\w.]){re.escape(column)}(?![\w])", text) is not None


@pytest.fixture(scope="module")
def tables():
    config = CompareConfig(truth_mesh="12x3x3", meshes=("4x1x1",), steps=3, seeds=1,
                           estimators=("rls", "enkf"))  # fmt: skip
    return compare(config)


def test_every_run_and_trace_column_is_documented(tables):
    text = PAGE.read_text(encoding="utf-8")
    runs, traces = tables
    missing = [
        f"{table}: {c}"
        for table, df in (("runs.parquet", runs), ("traces.parquet", traces))
        for c in df.columns
        if not documented(c, text, ("E",))
    ]
    assert not missing, f"{PAGE.name} does not document {missing}"

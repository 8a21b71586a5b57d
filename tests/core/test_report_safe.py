"""Shared outputs are safe to open: hostile names and messages.

An estimator registered under a name full of markup, a table pipe, a newline
and terminal control sequences (an OSC 8 hyperlink, a screen clear), and one
that fails with the same text as its message: report.md must hold no raw
HTML, no ESC byte may reach stdout or stderr, and table rows stay one line.
"""

from __future__ import annotations

import pandas as pd
import pytest

from idbench.cli.commands import main
from idbench.core.sanitize import markdown_cell, printable

HOSTILE = "a|b\n<img src=x onerror=alert(1)>\x1b]8;;http://x\x07link\x1b]8;;\x07\x1b[2J"

PLUGIN = f"""
    from dataclasses import dataclass

    import idbench
    from idbench_filters.rls import Rls

    HOSTILE = {HOSTILE!r}


    @dataclass
    class Hostile(Rls):
        pass


    @dataclass
    class Fails(Rls):
        def update(self, k, observation):
            raise ValueError(HOSTILE)


    @idbench.hookimpl
    def register_estimators(register):
        register(HOSTILE, Hostile)
        register("fails", Fails)
"""

TINY = ["--truth-mesh", "12x3x3", "--meshes", "4x1x1", "--steps", "3",
        "--seeds", "2"]  # fmt: skip


@pytest.fixture
def hostile(tmp_path, install):
    """The plugin installed under an entry point (as pip would)."""
    install("hostile", PLUGIN)
    return tmp_path / "out"


def no_control(text: str) -> None:
    for c in ("\x1b", "\x07", "\x9b"):
        assert c not in text, repr(text[max(0, text.find(c) - 60) : text.find(c) + 20])


def test_printable_leaves_no_control_character_and_one_line():
    s = printable(HOSTILE)
    no_control(s)
    assert "\n" not in s and "\\n" in s and "\\x1b]8;;" in s
    assert printable(s) == s  # idempotent: safe to apply twice
    md = markdown_cell(HOSTILE)
    assert "<" not in md and "&lt;img" in md and "a\\|b" in md
    assert printable("bidi \u202etxt.exe") == "bidi \\u202etxt.exe"


def test_hostile_names_and_messages_stay_text_everywhere(hostile, capsys):
    out = hostile
    argv = ["compare", *TINY, "--estimators", f"{HOSTILE},fails", "--out", str(out)]
    assert main(argv) == 0
    captured = capsys.readouterr()
    no_control(captured.out + captured.err)
    runs = pd.read_parquet(out / "runs.parquet")
    assert set(runs["estimator"]) == {HOSTILE, "fails"}  # the data keeps the name
    assert (runs.loc[runs["estimator"] == "fails", "status"] == "failed").all()
    rows = [line for line in captured.out.splitlines() if line.startswith("bend-y")]
    assert len(rows) == 2  # one row per estimator, each on one line
    assert any(printable(HOSTILE) in r for r in rows)
    assert any("fails" in r and "failed 2" in r and "ValueError" in r for r in rows)

    for fmt in ("csv", "markdown", "json"):
        assert main([*argv, "--format", fmt]) == 0
        captured = capsys.readouterr()
        no_control(captured.out + captured.err)

    assert main(["report", str(out), "--versus", HOSTILE]) == 0
    captured = capsys.readouterr()
    no_control(captured.out + captured.err)
    md = (out / "report.md").read_text()
    no_control(md)
    assert "<img" not in md and "&lt;img src=x onerror=alert(1)&gt;" in md
    summary = md.split("## Summary")[1].split("\n## ")[0]
    table = [line for line in summary.splitlines() if line.startswith("| bend-y")]
    assert len(table) == 2
    assert all(line.endswith("|") for line in table)
    cells = [line.count(" | ") for line in table]  # an escaped pipe splits no cell
    assert cells[0] == cells[1]
    page = (out / "report.html").read_text()
    no_control(page)
    assert "<img" not in page and "&lt;img src=x onerror=alert(1)&gt;" in page

    assert main(["plugins"]) == 0
    captured = capsys.readouterr()
    no_control(captured.out + captured.err)
    assert "hostile" in captured.out

"""--dry-run says what will run, what will be skipped and roughly what it costs."""

from __future__ import annotations

import re

from idbench.cli.commands import main


def test_dry_run_lists_skipped_runs_and_a_probed_cost(capsys, tmp_path):
    argv = ["compare", "--truth-mesh", "24x5x5", "--meshes", "4x1x1,16x4x4",
            "--estimators", "ukf,rls", "--steps", "3", "--seeds", "2",
            "--dry-run", "--out", str(tmp_path / "out")]  # fmt: skip
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert out.startswith("8 runs;"), out
    assert "2 runs will be skipped by their estimator:" in out
    assert "  ukf on 16x4x4: 2 runs" in out
    assert "ukf on 4x1x1" not in out  # under its budget: it runs
    seconds = re.search(r"forward solves take about (\d+) s", out)
    assert seconds and re.search(r"4x1x1: [\d.]+ ms, 16x4x4: [\d.]+ ms", out), out
    assert not (tmp_path / "out").exists()  # a dry run writes nothing


def _help(capsys, *argv: str) -> str:
    try:
        main(["compare", "--help", *argv])
    except SystemExit:
        pass
    return " ".join(capsys.readouterr().out.split())


def test_help_shows_the_defaults_of_the_body_given(capsys):
    beam = _help(capsys)
    assert "truth mesh spec (default: 80x11x11)" in beam
    kidney = _help(capsys, "--body", "kidney")
    assert "truth mesh spec (default: 16000)" in kidney
    assert "(default: solid)" in kidney  # --body is the solid model's option
    same = _help(capsys, "--model", "solid", "--model-option", "body=kidney")
    assert "truth mesh spec (default: 16000)" in same


def test_a_shorthand_picks_its_model(capsys, tmp_path):
    argv = ["compare", "--body", "kidney", "--estimators", "rls", "--seeds", "1",
            "--dry-run", "--out", str(tmp_path / "o")]  # fmt: skip
    assert main(argv) == 0
    assert "16000:" in capsys.readouterr().out

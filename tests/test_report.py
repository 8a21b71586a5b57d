"""``idbench report`` and ``compare --plot``."""

from __future__ import annotations

import pandas as pd
import pytest

from idbench.cli import main


@pytest.fixture()
def plotted(tmp_path, monkeypatch):
    monkeypatch.setenv("IDBENCH_CACHE_DIR", str(tmp_path / "cache"))
    out = tmp_path / "out"
    argv = ["compare", "--truth-mesh", "12x3x3", "--meshes", "4x1x1,6x2x2",
            "--steps", "4", "--seeds", "1", "--estimators", "rls,lms",
            "--out", str(out), "--plot", "-q"]  # fmt: skip
    assert main(argv) == 0
    return out


def test_plot_writes_figures_and_markdown(plotted):
    for stem in ("stiffness_vs_resolution", "shape_error", "estimates_vs_step"):
        for ext in ("png", "svg"):
            path = plotted / f"{stem}.{ext}"
            assert path.stat().st_size > 1000, path
    md = (plotted / "report.md").read_text()
    runs = pd.read_parquet(plotted / "runs.parquet")
    assert f"{len(runs)} runs" in md
    # one summary row per (scenario, mesh, estimator): 2 meshes x 2 estimators
    assert sum(1 for line in md.splitlines() if line.startswith("| bend-y")) == 4
    assert "![stiffness_vs_resolution](stiffness_vs_resolution.png)" in md


def test_report_command_rewrites_from_tables(plotted, capsys):
    (plotted / "report.md").unlink()
    assert main(["report", str(plotted)]) == 0
    assert (plotted / "report.md").exists()
    assert "report.md" in capsys.readouterr().out


def test_report_of_a_folder_without_results(tmp_path, capsys):
    assert main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "runs.parquet" in err and "Traceback" not in err

"""``idbench report`` and ``compare --plot``."""

from __future__ import annotations

import pandas as pd
import pytest

from idbench.cli.commands import main


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
    summary = md.split("## Real-time frontier")[0]
    assert sum(1 for line in summary.splitlines() if line.startswith("| bend-y")) == 4
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


def synthetic(steps=4):
    """Runs and traces where the frontier is known.

    ro-ukf 90 nodes: 0.011 s a step (median over two seeds), error 1.0 (mean);
    ro-ukf 240: 0.02 s, 0.5; rls 240: 0.025 s, 0.8 (dominated by ro-ukf 240);
    batch-ls 525: all its work (0.4 s) at the last step, amortised 0.1 s, 0.1;
    a failed run that would dominate everything must be ignored.
    """
    cases = [  # (run_id, nodes, estimator, seed, status, error, walls)
        ("a0", 90, "ro-ukf", 0, "ok", 0.9, [0.010] * steps),
        ("a1", 90, "ro-ukf", 1, "ok", 1.1, [0.012] * steps),
        ("b0", 240, "ro-ukf", 0, "ok", 0.5, [0.020] * steps),
        ("c0", 240, "rls", 0, "ok", 0.8, [0.025] * steps),
        ("d0", 525, "batch-ls", 0, "ok", 0.1, [0.0] * (steps - 1) + [0.4]),
        ("e0", 525, "lms", 0, "failed", 1e-6, [1e-6] * steps),
    ]
    runs = pd.DataFrame(
        {
            "run_id": c[0],
            "scenario": "bend-y",
            "mesh": f"m{c[1]}",
            "model_nodes": float(c[1]),
            "estimator": c[2],
            "seed": c[3],
            "status": c[4],
            "shape_error_final": c[5],
            "shape_error_mean_final": c[5] / 320,
            "wall_s_step": sum(c[6]) / steps,
        }
        for c in cases
    )
    traces = pd.DataFrame(
        {"run_id": c[0], "step": k, "wall_s": w}
        for c in cases
        for k, w in enumerate(c[6], start=1)
    )
    return runs, traces


def test_frontier_on_known_points():
    from idbench.report.write import frontier

    runs, traces = synthetic()
    table = frontier(runs, traces).set_index(["model_nodes", "estimator"])
    assert len(table) == 4  # the failed run is left out
    a = table.loc[(90.0, "ro-ukf")]
    assert a["seeds"] == 2
    assert a["shape_error_final"] == pytest.approx(1.0)
    assert a["wall_s_step"] == pytest.approx(0.011)
    assert a["rate_hz"] == pytest.approx(1 / 0.011)
    d = table.loc[(525.0, "batch-ls")]  # deferred work: charged total / steps
    assert d["wall_s_median"] == 0.0
    assert d["wall_s_step"] == pytest.approx(0.1)
    pareto = set(table.index[table["pareto"]])
    assert pareto == {(90.0, "ro-ukf"), (240.0, "ro-ukf"), (525.0, "batch-ls")}
    assert list(table.index[table["within_60hz"]]) == [(90.0, "ro-ukf")]
    assert set(table.index[table["within_30hz"]]) == {
        (90.0, "ro-ukf"), (240.0, "ro-ukf"), (240.0, "rls")}  # fmt: skip
    assert list(table.index[table["best_60hz"]]) == [(90.0, "ro-ukf")]
    assert list(table.index[table["best_30hz"]]) == [(240.0, "ro-ukf")]


def test_pareto_front_ties_and_nan():
    from idbench.report.write import pareto_front

    cost = [1.0, 1.0, 2.0, float("nan"), 0.5]
    error = [1.0, 1.0, 0.5, 0.0, 3.0]
    # equal points do not dominate each other; NaN is never on the front
    assert pareto_front(cost, error).tolist() == [True, True, True, False, True]


def test_write_report_draws_the_frontier(tmp_path):
    from idbench.report.write import write_report

    runs, traces = synthetic()
    runs["E_final"], runs["E_true"] = 4000.0, 5000.0
    runs["shape_error_direct"] = 2.0
    runs.to_parquet(tmp_path / "runs.parquet")
    traces.to_parquet(tmp_path / "traces.parquet")
    written = write_report(tmp_path)
    for ext in ("png", "svg"):
        path = tmp_path / f"realtime_frontier.{ext}"
        assert path in written and path.stat().st_size > 1000
    md = (tmp_path / "report.md").read_text()
    assert "## Real-time frontier" in md
    assert "![realtime_frontier](realtime_frontier.png)" in md


def test_plot_of_a_compare_includes_the_frontier(plotted):
    assert (plotted / "realtime_frontier.png").stat().st_size > 1000
    assert "best_30hz" in (plotted / "report.md").read_text()

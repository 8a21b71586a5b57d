"""The core knows no model: a spring chain whose parameter is k, end to end.

A non-beam model (its parameter is ``k``, its state the displacements of a 1-D
chain, its scenarios its own) registered through a plugin runs through
``compare()`` and ``write_report()``: every figure is written, the summary's
ratio column is filled, the tables' columns follow its names and probes.
"""

from __future__ import annotations

import pandas as pd
import pytest
from support.helpers import registry_with
from support.springs import SpringPlugin

from idbench.plan.config import CompareConfig
from idbench.report.write import parameter_names, summarise, summary_text, write_report
from idbench.run.compare import compare


@pytest.fixture
def registry():
    return registry_with({"springs": SpringPlugin()})


def run(registry, tmp_path, **kw):
    cfg = CompareConfig(
        model="spring-chain",
        estimators=("rls", "ro-ukf"),
        seeds=2,
        steps=6,
        obs_every=(1,),
        noise=(1e-4,),
        **kw,
    )
    out = tmp_path / "out"
    runs, traces = compare(cfg, out, registry=registry)
    return out, runs, traces


def test_spring_chain_report_has_every_figure(registry, tmp_path):
    out, runs, traces = run(registry, tmp_path)
    assert (runs["status"] == "ok").all(), runs[["status", "error"]]
    assert parameter_names(runs) == ["k"]
    # columns follow the model: k_*, its probe 'end'; nothing of the beam's
    assert {"k_true", "k_final", "k_ref", "k_std_final"} <= set(runs.columns)
    assert (runs["k_true"] == 50.0).all() and runs["model_nodes"].notna().all()
    assert not any(c.startswith(("E", "nu", "tip")) for c in runs.columns)
    assert "end" in traces.columns and "tip_x" not in traces.columns
    assert runs["transfer_error"].notna().all()  # pull -> pull-hard, its own
    summary = summarise(runs)
    assert len(summary) == 4  # 2 meshes x 2 estimators, seeds pooled
    assert summary["n"].tolist() == [2, 2, 2, 2]
    assert summary["k_ratio"].notna().all()
    assert summary["k_ratio"].between(0.5, 1.0).all()  # coarse chains: low k
    # the coarse chain (5 nodes) identifies a lower k than the fine one (20)
    by_mesh = summary.groupby("mesh")["k_ratio"].mean()
    assert by_mesh["5"] < by_mesh["20"]
    written = write_report(out)
    for stem in (
        "stiffness_vs_resolution",
        "shape_error",
        "estimates_vs_step",
        "uncertainty",
        "realtime_frontier",
    ):
        for ext in ("png", "svg"):
            path = out / f"{stem}.{ext}"
            assert path in written and path.stat().st_size > 1000, path
    md = (out / "report.md").read_text()
    assert "k / k_true" in md and "E" not in md.split("## Summary")[1].split("|")[1]
    page = (out / "report.html").read_text()
    assert page.count("<svg") == 5
    assert "k / k_true" in page
    assert "E / E_true" not in summary_text(runs)


def test_two_parameters_get_small_multiples(registry, tmp_path):
    out, runs, _ = run(
        registry, tmp_path, model_settings={"spring-chain": {"p": 2}}
    )
    assert parameter_names(runs) == ["k_0", "k_1"]
    summary = summarise(runs)
    assert summary[["k_0_ratio", "k_1_ratio"]].notna().all().all()
    from idbench.report.write import figures

    traces = pd.read_parquet(out / "traces.parquet")
    figs = figures(runs, traces)
    visible = [ax for ax in figs["stiffness_vs_resolution"].axes if ax.get_visible()]
    assert [ax.get_title() for ax in visible] == [
        "k_0 against resolution",
        "k_1 against resolution",
    ]
    steps = [ax for ax in figs["estimates_vs_step"].axes if ax.get_visible()]
    assert len(steps) == 2
    assert all(float(t).is_integer() for t in steps[0].get_xticks())


def test_frontier_figure_without_ok_runs(tmp_path):
    runs = pd.DataFrame(
        {"run_id": ["a"], "scenario": ["s"], "mesh": ["m"], "model_nodes": [9.0],
         "estimator": ["rls"], "seed": [0], "status": ["failed"],
         "error": ["RuntimeError: boom"]}
    )  # fmt: skip
    runs.to_parquet(tmp_path / "runs.parquet")
    written = write_report(tmp_path)
    assert tmp_path / "realtime_frontier.svg" in written
    assert "RuntimeError: boom" in summary_text(runs)


def test_study_values_are_overlaid_and_labelled(registry, tmp_path):
    from idbench.report.figures import STUDY_LABEL
    from idbench.report.write import figures

    out, runs, traces = run(registry, tmp_path)
    study = pd.DataFrame(
        {"figure": ["stiffness_vs_resolution", "shape_error"], "x": [5, 20],
         "y": [0.6, 0.01]}
    )  # fmt: skip
    figs = figures(runs, traces, study)
    for stem in ("stiffness_vs_resolution", "shape_error"):
        labels = [t.get_text() for t in figs[stem].legends[0].get_texts()]
        assert STUDY_LABEL in labels, stem
    assert "read off the paper's figure" in STUDY_LABEL
    labels = [
        t.get_text() for t in figures(runs, traces)["shape_error"].legends[0].texts
    ]
    assert STUDY_LABEL not in labels  # nothing given, nothing drawn
    study.to_csv(out / "study_values.csv", index=False)
    write_report(out)
    assert "read off the paper" in (out / "stiffness_vs_resolution.svg").read_text()

"""Each study runs in --quick mode and shows its claim on one number."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest


def test_fig2_identified_E_rises_with_resolution_and_stays_below_truth(study, tmp_path):
    table = study("fig2_stiffness_vs_resolution").compute(quick=True, out=tmp_path)
    ro = table[table["estimator"] == "ro-ukf"].sort_values("model_nodes")
    assert len(ro) == 3
    assert np.all(np.diff(ro["E"].to_numpy()) > 0)  # approaches E_true from below
    assert np.all(ro["ratio"] < 1.0)


def test_fig3_fig4_effective_E_depends_on_direction_and_strength(study, tmp_path):
    module = study("fig3_fig4_effective_stiffness")
    table = module.compute(quick=True, out=tmp_path)
    eff = table.pivot(index="step", columns="scenario", values="eff_ratio")
    assert eff["stretch-x"].min() > eff["bend-y"].max() + 0.3  # direction
    assert eff["stretch-x"].iloc[0] - eff["stretch-x"].iloc[-1] > 0.03  # strength
    last = table[table["step"] == table["step"].max()]
    # the filter ends on the level's best constant, found independently
    np.testing.assert_allclose(last["E_ukf"], last["E_eff"], rtol=0.05)
    module.plot(table, tmp_path / "fig.png")
    assert (tmp_path / "fig.png").stat().st_size > 10_000


def test_calibrated_E_predicts_a_held_back_stretch_one_constant_misses(study, tmp_path):
    module = study("calibrated_stiffness")
    cal, fit, scores = module.compute(quick=True, out=tmp_path)
    err = scores.pivot(index="scenario", columns="method", values="shape_error_path")
    assert err.loc["stretch-x", "calibrated"] < 0.5 * err.loc["stretch-x", "constant"]
    # on bending-like held-back paths it is as good as the bending constant
    bending = ["mixed-30", "mixed-60", "bend-z"]
    assert np.all(err.loc[bending, "calibrated"] < 1.5 * err.loc[bending, "constant"])
    assert np.all(err.loc[bending, "calibrated"] < 0.2 * err.loc[bending, "E_true"])
    assert set(fit["coordinates"]) == {"angle, fraction", "tip", "tip_angle"}
    module.plot(cal, scores, tmp_path / "fig.png")
    assert (tmp_path / "fig.png").stat().st_size > 10_000


def test_uncertainty_coarse_meshes_are_confidently_wrong_the_control_is_not(
    study, tmp_path
):
    module = study("uncertainty_calibration")
    table = module.compute(quick=True, out=tmp_path)
    coarse = table[table["case"] != "= truth"]
    control = table[table["case"] == "= truth"]
    # no estimator's 95% interval holds E_true on the coarse mesh, model error
    # term or not; with mesh = truth the batch fit's does at both noise levels
    assert (coarse["cover95_true"] == 0).all()
    ls = control[control["estimator"] == "batch-ls"]
    assert len(ls) == 2 and (ls["cover95_true"] == 1).all()
    # against its own model's posterior the batch fit is calibrated
    assert (coarse.loc[coarse["estimator"] == "batch-ls", "cover95_post"] == 1).all()
    # the remedy widens the reported std where the misfit exceeds the noise
    by = coarse[coarse["noise"] == 1e-4].set_index("estimator")
    assert by.loc["ro-ukf+me", "E_std"] > 1.2 * by.loc["ro-ukf", "E_std"]
    module.plot(table, tmp_path / "fig.png")
    assert (tmp_path / "fig.png").stat().st_size > 10_000


def test_over_seeds_means_spreads_constants_and_counts(study):
    _cli = study("_cli")
    runs = pd.DataFrame(
        {
            "mesh": ["b", "b", "a", "a", "a"],
            "E_final": [1.0, 3.0, 2.0, 4.0, 9.0],
            "E_true": [5.0] * 5,
            "seed": [0, 1, 0, 1, 2],
        }
    )
    table = _cli.over_seeds(
        runs, ["mesh"], sd=("E",), first=("E_true",), count="n", E="E_final"
    )
    assert list(table.columns) == ["mesh", "E", "E_sd", "E_true", "n"]
    assert table["mesh"].tolist() == ["a", "b"]  # sorted groups
    assert table["E"].tolist() == [5.0, 2.0]
    assert table["E_sd"].tolist() == pytest.approx(
        [np.std([2, 4, 9], ddof=1), np.sqrt(2)]
    )
    assert table["n"].tolist() == [3, 2] and table["E_true"].tolist() == [5.0, 5.0]
    unsorted = _cli.over_seeds(runs, ["mesh"], sort=False, E="E_final")
    assert unsorted["mesh"].tolist() == ["b", "a"]
    assert list(unsorted.columns) == ["mesh", "E"]  # no spread unless asked


ORGAN_STUDIES = ("organ_discretization", "point_clouds", "realtime_frontier",
                 "physical_stiffness")  # fmt: skip


def test_a_full_organ_study_writes_its_report_with_the_view(study, tmp_path):
    from pathlib import Path

    from support.helpers import tiny

    from idbench.run.compare import compare

    cli = study("_cli")
    out = tmp_path / "out"
    compare(tiny(), out)
    cli.report(out, quick=True)  # a quick run: no report
    cli.report(None, quick=False)  # no folder: none
    assert not (out / "report.html").exists()
    cli.report(out, quick=False)
    assert 'id="view3d-data"' in (out / "report.html").read_text()
    studies = Path(__file__).resolve().parents[2] / "studies"
    for name in ORGAN_STUDIES:  # each where it runs compare into a folder
        assert "_cli.report(" in (studies / f"{name}.py").read_text(), name

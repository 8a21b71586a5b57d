"""The real-time frontier study runs in --quick mode and shows its claim."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest


def test_full_ukf_costs_more_than_ro_ukf_on_the_same_mesh(study, tmp_path):
    module = study("realtime_frontier")
    table = module.compute(quick=True, out=tmp_path)
    # the full UKF fits its (quick) budget of solves only on the coarsest mesh
    ukf = table[table["estimator"] == "ukf"]
    assert len(ukf) == 1
    nodes = ukf["model_nodes"].iloc[0]
    ro = table[(table["estimator"] == "ro-ukf") & (table["model_nodes"] == nodes)]
    # 2n + 1 = 99 sigma-point solves a step against the RO-UKF's 2; batched
    # (step_many: most sigma points converge at their predictions) the full
    # UKF costs a few RO-UKF steps here, no longer tens
    ratio = ukf["wall_s_step"].iloc[0] / ro["wall_s_step"].iloc[0]
    assert ratio > 1, ratio
    # the frontier answers the budget question: one best row per budget, if
    # any row fits it (none may on a loaded machine: no rate is asserted)
    assert table["best_30hz"].sum() == int(table["within_30hz"].any())
    assert np.all(table.loc[table["best_30hz"], "within_30hz"])
    module.plot(table, tmp_path / "realtime_frontier.png")
    assert (tmp_path / "realtime_frontier.png").stat().st_size > 1000


def test_organ_frontier_quick_has_rates_shape_errors_and_moduli(study, tmp_path):
    pytest.importorskip("gmsh")  # the liver's meshes are made on first use
    module = study("realtime_frontier")
    table = module.compute_organ("liver", quick=True, out=tmp_path)
    quick = module.ORGAN_QUICK
    # one row per (mesh, estimator), every one with a rate, an error and an E
    assert len(table) == len(quick["meshes"]) * len(quick["estimators"])
    assert set(table["estimator"]) == set(quick["estimators"])
    assert table["model_nodes"].nunique() == len(quick["meshes"])
    assert np.all(table["rate_hz"] > 0)
    assert np.all(np.isfinite(table["shape_error_final"]))
    ratio = table["E_final"] / table["E_true"]
    assert np.all((ratio > 0.3) & (ratio < 3)), ratio.tolist()
    module.plot(table, tmp_path / "f.png", "liver grasp-lift")
    # the docs' table and the CSV are written by the study itself
    module.save(table, tmp_path / "saved")
    csv = pd.read_csv(tmp_path / "saved" / "realtime_frontier.csv")
    assert list(csv.columns) == list(table.columns) and len(csv) == len(table)
    md = (tmp_path / "saved" / "realtime_frontier.md").read_text().splitlines()
    assert "E_final / E_true" in md[0] and "30 Hz" in md[0]
    assert len(md) == 2 + len(table)  # header, rule, one line a row
    first = table.sort_values(["model_nodes", "rate_hz"], ascending=[True, False])
    first = first.iloc[0]
    cells = [c.strip() for c in md[2].strip("|").split("|")]
    assert cells[1] == first["estimator"]
    assert float(cells[2]) == pytest.approx(first["rate_hz"], rel=5e-3)
    assert float(cells[4]) == pytest.approx(ratio[first.name], abs=5e-4)
    assert cells[5] == ("yes" if first["within_30hz"] else "no")
    assert (tmp_path / "f.png").stat().st_size > 1000
    with pytest.raises(ValueError, match="organ 'heart': allowed are liver, kidney"):
        module.compute_organ("heart", quick=True)


def test_organ_moduli_and_markdown_name_every_region(study):
    # the kidney has two moduli (E_parenchyma, E_inclusion), no E_final column
    module = study("realtime_frontier")
    runs = pd.DataFrame(
        {
            "model_nodes": [506, 506, 506],
            "estimator": ["ro-ukf", "ro-ukf", "rls"],
            "status": ["ok", "ok", "failed"],
            "E_parenchyma_final": [2000.0, 3000.0, np.nan],
            "E_parenchyma_std_final": [1.0, 1.0, np.nan],
            "E_parenchyma_true": [5000.0] * 3,
            "E_inclusion_final": [9000.0, 11000.0, np.nan],
            "E_inclusion_true": [20000.0] * 3,
            "shape_error_final": [0.1, 0.1, np.nan],
        }
    )
    E = module.moduli(runs)
    assert len(E) == 1  # the failed run counts nowhere
    row = E.iloc[0]
    assert row["E_parenchyma_final"] == 2500.0 and row["E_inclusion_final"] == 10000.0
    assert row["E_inclusion_true"] == 20000.0
    assert "E_parenchyma_std_final" not in E.columns
    table = E.assign(
        rate_hz=[42.0],
        shape_error_mean_final=[0.00051],
        within_30hz=[True],
        within_60hz=[False],
    )
    head, _, line = module.markdown(table).splitlines()
    assert "E_parenchyma_final / E_parenchyma_true" in head
    assert "E_inclusion_final / E_inclusion_true" in head
    assert line == "| 506 | ro-ukf | 42 | 0.51 | 0.500 | 0.500 | yes | no |"

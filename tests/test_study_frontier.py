"""The real-time frontier study runs in --quick mode and shows its claim."""

from __future__ import annotations

import numpy as np


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
    # the frontier answers the budget question: one best row per budget
    assert table["best_30hz"].sum() == 1
    assert np.all(table.loc[table["best_30hz"], "within_30hz"])
    module.plot(table, tmp_path / "realtime_frontier.png")
    assert (tmp_path / "realtime_frontier.png").stat().st_size > 1000

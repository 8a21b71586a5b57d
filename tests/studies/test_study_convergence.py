"""The convergence study runs in --quick mode and measures what it claims to."""

from __future__ import annotations

import numpy as np


def test_convergence_quick_settles_with_consistent_intervals(study, tmp_path):
    module = study("convergence_sparse_data")
    table = module.compute(quick=True, out=tmp_path)
    steps = module.QUICK["steps"]

    # every level of every axis has the four estimators on the main mesh
    for axis, levels in module.QUICK["axes"].items():
        for level in levels:
            here = table[(table["axis"] == axis) & np.isclose(table["level"], level)]
            assert set(module.ESTIMATORS) <= set(here["method"])
    # censored settling steps: 1..K+1, the bootstrap interval brackets the mean
    assert table["settle"].between(1, steps + 1).all()
    assert (table["settle_lo"] <= table["settle"] + 1e-12).all()
    assert (table["settle"] <= table["settle_hi"] + 1e-12).all()
    assert table["never"].between(0, 1).all()

    dense = table[(table["axis"] == "obs_every") & (table["level"] == 1)]
    settle = dense.set_index("method")["settle"]
    obs = dense.set_index("method")["settle_obs"]
    # batch LS refitted at every observation agrees with E_ref from the first one
    assert obs["batch-ls"] == 1
    # with data at every step the RO-UKF settles no later than LMS
    assert settle["ro-ukf"] <= settle["lms"]

    verdicts = module.verdict(table)
    assert len(verdicts) == sum(len(v) for v in module.QUICK["axes"].values())

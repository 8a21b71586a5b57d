"""The load-capture study runs in --quick mode and splits the push's drop."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gmsh")


def test_a_conserved_push_lifts_e_and_the_grasp_is_the_same_load(study, tmp_path):
    module = study("load_capture")
    table = module.compute(quick=True, out=tmp_path)
    assert (table["status"] == "ok").all(), table
    grasp = table[table["manipulation"] == "grasp-lift"]
    np.testing.assert_allclose(grasp["load_resultant_ratio"], 1.0, atol=1e-9)
    push = table[table["manipulation"] == "lateral-push"].set_index(
        ["conserve", "estimator"]
    )
    assert (push.loc["none", "load_resultant_ratio"] < 0.98).all()
    np.testing.assert_allclose(push.loc["resultant", "load_resultant_ratio"], 1.0,
                               atol=1e-9)  # fmt: skip
    lifted = push.loc["resultant", "E_ratio"] - push.loc["none", "E_ratio"]
    assert (lifted > 0.1).all(), lifted  # the lighter load was read as stiffness
    parts = module.split(table).set_index("manipulation")
    row = parts.loc["lateral-push"]
    assert row["drop"] == pytest.approx(row["from_load"] + row["from_stiffness"])
    assert "| liver | lateral-push |" in module.markdown(table)
    module.plot(table, tmp_path / "fig.png")
    assert (tmp_path / "fig.png").stat().st_size > 10_000

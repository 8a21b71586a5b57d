"""The unknown-supports study runs in --quick mode and shows its claims on numbers."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gmsh")


def test_a_clamp_on_a_liver_held_by_springs_costs_e(study, tmp_path):
    module = study("unknown_supports")
    table = module.compute(quick=True, out=tmp_path)
    assert (table["status"] == "ok").all(), table
    by = table.set_index("design")
    # the price of a wrong support: a clamp makes the body too stiff, so the
    # E it finds is far below the E that the right springs find
    assert by.loc["clamp", "E_vs_known"] < 0.8
    assert np.isfinite(by.loc["identified", "k_n_posterior_ratio"])
    reg = module.registration(quick=True, out=tmp_path)
    own = reg[reg["surface"].str.startswith("truth")]
    # 10 mm, 10 degrees off: the truth's cloud comes back onto its own surface
    assert (own["worst_error_mm"] < 1.0).all(), own
    module.plot(table, tmp_path / "fig.png")
    assert (tmp_path / "fig.png").stat().st_size > 10_000

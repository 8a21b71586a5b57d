"""The reduced-models study runs in --quick mode and shows its claim on one number."""

from __future__ import annotations

import pytest

pytest.importorskip("gmsh")


def test_a_reduced_fine_mesh_finds_the_fine_meshs_E(study, tmp_path):
    module = study("reduced_models")
    table = module.compute(quick=True, out=tmp_path)
    rows = table.set_index("kind")
    # the reduction of the fine mesh identifies the full fine model's E (within
    # 2%), where the coarse mesh identifies a low one
    assert abs(rows.loc["reduced", "E_vs_full"] - 1.0) < 0.02
    assert rows.loc["coarse", "E_ratio"] < 0.9
    assert rows.loc["reduced", "modes"] == 30
    errors = module.reduction_errors(quick=True)
    assert (errors["reduction_error"] < 0.05).all()
    assert "rom:1000:30" in module.markdown(table)
    module.plot(table, tmp_path / "fig.png")
    assert (tmp_path / "fig.png").stat().st_size > 10_000
